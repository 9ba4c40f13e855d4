"""Physically based scene simulator (Mitsuba 3): AIR-BRF-like multi-angle hyperspectral acquisitions.

Library entry points::

    from brfgs.sim import SimConfig, simulate, render_views
    path = simulate(out_dir, SimConfig.tiny("testsite"))          # a small scene folder with truth/
    out = render_views(SimConfig.tiny(), [(38.0, 150.0)])         # clean reflectance of extra views

Modules: spectra (material/illumination/noise spectra), materials (material table), meshes
(mesh primitives and noise), geometry (procedural scenes, numpy), render (Mitsuba scene, 3 bands
per pass), config (SimConfig), acquisition (acquisition, noise, files).
"""

from brfgs.sim.acquisition import (SimConfig, observe, render_scene_views, render_seed, render_views, simulate,
                                view_name)

__all__ = ["SimConfig", "simulate", "render_views", "render_scene_views", "observe", "render_seed", "view_name"]
