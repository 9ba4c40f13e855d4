"""The model: Gaussians (paper eqs. 10-11), their features, the trained-model file and the one
render path.

    from brfgs.model import TrainedModel, render
    tm = TrainedModel.load("run/")                       # model.safetensors, validated, no code runs
    rv = render(tm, tm.cameras[0])                       # latent, cube [H, W, B], cir, alpha, depth
    rv = render(tm, cam, sun_zenith_deg=50, normals=True)

Modules: gaussians.py (parameter container, initialisation), densify.py (split/clone/prune),
optim.py (Adam over named tensors), camera.py (cameras, scene description), features.py
(per-Gaussian features: stage-1 colours, the head's latent, geometry channels), render.py
(rasterize + composite + decode: :func:`render`), trained.py (:class:`TrainedModel`),
io.py (safetensors files), schema.py (validation of model files).
"""

from brfgs.model.camera import Camera, camera_from_c2w, camera_from_intrinsics, scene_description
from brfgs.model.densify import DensifyConfig, DensifyState, refine, reset_opacity
from brfgs.model.gaussians import APPEARANCES, GaussianModel, init_from_points, scene_extent, surface_fill
from brfgs.model.optim import NamedAdam
from brfgs.model.render import RenderedView, render
from brfgs.model.trained import MODEL_FILE, TrainedModel

__all__ = ["APPEARANCES", "Camera", "DensifyConfig", "DensifyState", "GaussianModel", "MODEL_FILE", "NamedAdam",
           "RenderedView", "TrainedModel", "camera_from_c2w", "camera_from_intrinsics", "init_from_points", "refine",
           "render", "reset_opacity", "scene_description", "scene_extent", "surface_fill"]
