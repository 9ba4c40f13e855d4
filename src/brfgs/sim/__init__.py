"""Physically based scene simulator (Mitsuba 3): AIR-BRF-like multi-angle hyperspectral acquisitions.

Library entry points::

    from brfgs.sim import SimConfig, simulate, render_views
    path = simulate(out_dir, SimConfig.tiny("testsite"))          # a small scene folder with truth/
    out = render_views(SimConfig.tiny(), [(38.0, 150.0)])         # clean reflectance of extra views

Modules: spectra (material/illumination/noise spectra), materials (material table), meshes
(mesh primitives and noise), geometry (procedural scenes, numpy), render (Mitsuba scene, 3 bands
per pass), config (SimConfig), acquisition (acquisition, noise, files).
"""

import importlib

# Names exported here load on first use (PEP 562), so that the command line can read the options
# (brfgs.sim.options) without Mitsuba.
_EXPORTS = {"brfgs.sim.acquisition": ("SimConfig", "observe", "render_scene_views", "render_seed", "render_views",
                                      "simulate", "view_name")}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'brfgs.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
