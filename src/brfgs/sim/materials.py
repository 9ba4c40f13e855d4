"""Material library of the simulated scenes: BSDF kind and spectra on the 1 nm grid.

Every material has a fixed id (``MATERIAL_IDS``; 0 means "no surface") so material-id maps
of different scenes agree. Spectra come from :mod:`brfgs.sim.spectra` (PROSPECT-D, SAIL,
prosail soils, documented analytic curves).

BSDF kinds (all Mitsuba 3 plugins):

* ``diffuse``: Lambertian; a textured material's reflectance is
  ``brightness(x, y) · (mix(x, y) · end1 + (1 − mix(x, y)) · end2)``.
* ``leaf``: thin Lambertian leaf facet that reflects ``R`` and transmits ``T`` diffusely
  on both sides (PROSPECT-D R and T); a Mitsuba BSDF plugin written in Python
  (:class:`brfgs.sim.render.LeafBSDF`), since Mitsuba 3 ships no diffuse transmitter.
* ``plastic``: Mitsuba ``roughplastic`` — a rough dielectric interface (GGX roughness
  ``alpha``, index ``ior``) over a diffuse substrate (Weidlich–Wilkie layering). Used for
  car clear-coat paint (ior 1.5) and for the pond, whose wind-roughened water surface
  (ior 1.333, GGX α = 0.12 ≈ Cox–Munk slopes at ~2 m/s) produces the sun glint while the
  substrate stands for the water column's volume reflectance. (A bare ``roughdielectric``
  over a pond bed would leave the bed unlit: shadow rays toward a directional sun cannot
  refract through a dielectric in a path tracer.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brfgs.sim import spectra as sp

MATERIAL_NAMES = ["none", "grass", "soil", "concrete", "asphalt", "water", "roof", "concrete_wall",
                  "paint_red", "paint_white", "paint_blue", "paint_silver", "broadleaf", "bark", "shrub",
                  "dry_grass", "needles", "straw", "soil_plain"]
MATERIAL_IDS = {n: i for i, n in enumerate(MATERIAL_NAMES)}

VEGETATION = ("grass", "broadleaf", "shrub", "needles", "dry_grass")


@dataclass
class Material:
    """One material: name, BSDF kind and spectra [651] on spectra.GRID_NM.

    ``end1``/``end2``: reflectance end-members (equal for untextured materials);
    ``transmittance``: leaves only; ``alpha``/``ior``: plastic only.
    """

    name: str
    kind: str
    end1: np.ndarray
    end2: np.ndarray
    transmittance: np.ndarray | None = None
    alpha: float = 0.0
    ior: float = 1.5
    description: str = ""

    @property
    def id(self) -> int:
        return MATERIAL_IDS[self.name]


def _grass_bhr():
    return sp.sail_bhr(1.5, 40.0, 8.0, 0.0, 0.012, 0.005, 3.0, 60.0, 1.0, 0.5)


def _dry_grass_bhr():
    return sp.sail_bhr(1.5, 8.0, 5.0, 0.8, 0.004, 0.008, 1.5, 65.0, 1.0, 0.8)


def _straw_bhr():
    return sp.sail_bhr(2.0, 2.0, 3.0, 1.2, 0.001, 0.012, 8.0, 50.0, 1.0, 0.8)


# Untextured diffuse materials: (spectrum of spectra, description).
_UNIFORM_DIFFUSE = {
    "concrete": (sp.concrete, "weathered concrete yard (analytic, spectra.concrete)"),
    "concrete_wall": (sp.concrete, "concrete walls (spectra.concrete)"),
    "asphalt": (sp.asphalt, "aged asphalt road (spectra.asphalt)"),
    "roof": (sp.bitumen_roof, "flat bitumen roof (spectra.bitumen_roof)"),
    "bark": (sp.bark, "tree trunks (spectra.bark)"),
}
# Leaf materials: (PROSPECT-D N, Cab, Car, Cbrown, Cw, Cm, Ant), description.
_LEAVES = {
    "broadleaf": ((1.6, 45.0, 9.0, 0.0, 0.012, 0.006, 1.0),
                  "broadleaf: PROSPECT-D N 1.6 Cab 45 Car 9 Cw .012 Cm .006 Ant 1"),
    "shrub": ((1.8, 35.0, 8.0, 0.1, 0.010, 0.007, 0.5), "shrub leaves: PROSPECT-D N 1.8 Cab 35 Cbrown .1"),
    "needles": ((2.2, 55.0, 12.0, 0.05, 0.020, 0.020, 0.0), "conifer needles: PROSPECT-D N 2.2 Cab 55 Cm .02"),
}


def material(name: str) -> Material:
    """The material called ``name`` (one of MATERIAL_NAMES except "none")."""
    if name in _UNIFORM_DIFFUSE:
        spectrum, description = _UNIFORM_DIFFUSE[name]
        c = spectrum()
        return Material(name, "diffuse", c, c, description=description)
    if name in _LEAVES:
        params, description = _LEAVES[name]
        r, t = sp.prospect_leaf(*params)
        return Material(name, "leaf", r, r, t, description=description)
    if name == "grass":
        return Material(name, "diffuse", _grass_bhr(), sp.soil(1.0, 0.3),
                        description="turf: SAIL BHR of a PROSPECT-D canopy (LAI 3, Cab 40) mixed with moist soil")
    if name == "soil":
        s1, s2 = sp.soil_endmembers()
        return Material(name, "diffuse", s1, s2, description="prosail dry (rsoil1) / wet (rsoil2) soil mixture")
    if name == "soil_plain":
        return Material(name, "diffuse", sp.soil(1.0, 0.6), sp.soil(1.0, 0.6),
                        description="uniform prosail soil, 60 % dry")
    if name == "water":
        w = sp.water_body()
        return Material(name, "plastic", w, w, alpha=0.12, ior=1.333,
                        description="pond: rough water surface (GGX alpha 0.12, n 1.333) over the water column "
                                    "reflectance spectra.water_body")
    if name.startswith("paint_"):
        p = sp.paint(name[6:])
        return Material(name, "plastic", p, p, alpha=0.05 if name != "paint_silver" else 0.12, ior=1.5,
                        description=f"car paint: clear coat (GGX, n 1.5) over {name[6:]} pigment (spectra.paint)")
    if name == "dry_grass":
        return Material(name, "diffuse", _dry_grass_bhr(), sp.soil(1.0, 0.8),
                        description="dry grassland: SAIL BHR of senescent PROSPECT-D leaves (Cab 8, Cbrown .8, LAI 1.5)"
                                    " mixed with dry soil")
    if name == "straw":
        s = _straw_bhr()
        return Material(name, "diffuse", s, s, description="haystack: SAIL BHR of a thick (LAI 8) layer of straw "
                                                          "(PROSPECT-D Cab 2, Cbrown 1.2, Cw .001)")
    raise ValueError(f"unknown material {name!r}")
