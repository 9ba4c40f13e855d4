"""The model: Gaussians (paper eqs. 10-11), their features, the trained-model file and the one
render path.

    from brfgs.model import TrainedModel, render
    tm = TrainedModel.load("run/")                       # model.safetensors, validated, no code runs
    rv = render(tm, tm.cameras[0])                       # latent, cube [H, W, B], cir, alpha, depth
    rv = render(tm, cam, sun_zenith_deg=50, normals=True)

Modules: gaussians.py (parameter container, initialisation), densify.py (split/clone/prune), mcmc.py
(3DGS-MCMC relocation), densify_config.py (the strategies' options),
optim.py (Adam over named tensors), camera.py (cameras, scene description), features.py
(per-Gaussian features: stage-1 colours, the head's latent, geometry channels), rendering.py
(rasterize, composite, decode: the pieces), view.py (:func:`render`), trained.py (:class:`TrainedModel`),
io.py (safetensors files), schema.py (validation of model files).
"""

import importlib

# Names exported here, by module. They load on first use (PEP 562), so that light modules such
# as brfgs.model.densify_config can be imported (by the command line) without torch.
_EXPORTS = {
    "brfgs.model.camera": ("Camera", "camera_from_c2w", "camera_from_intrinsics", "scene_description"),
    "brfgs.model.densify": ("DensifyState", "refine", "reset_opacity"),
    "brfgs.model.densify_config": ("ADCConfig", "MCMCConfig"),
    "brfgs.model.gaussians": ("APPEARANCES", "GaussianModel", "init_from_points", "scene_extent", "surface_fill"),
    "brfgs.model.optim": ("NamedAdam",),
    "brfgs.model.view": ("RenderedView", "render"),
    "brfgs.model.trained": ("MODEL_FILE", "RenderSettings", "TrainedModel"),
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'brfgs.model' has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
