"""Gaussians (paper eqs. 10-11): parameter container, initialisation, densification, rendering.

    from brfgs.model import GaussianModel, init_from_points
    model = init_from_points(points[P,3], colors[P,k], latent_dim=16)
    feats = gaussian_features(model, camera, sun_dir, head_cfg)   # [N, C] per view
    out = rasterize_features(model, feats, camera)                # brfgs.render.rasterize
"""

from brfgs.model.densify import DensifyConfig, DensifyState, refine, reset_opacity
from brfgs.model.gaussians import APPEARANCES, GaussianModel, init_from_points, scene_extent, surface_fill
from brfgs.model.optim import NamedAdam
from brfgs.model.render import (Camera, NeuralHead, camera_from_c2w, centred_hybrid_latent, decode_image,
                                gaussian_features, rasterize_features, uncentre, view_dirs)

__all__ = ["APPEARANCES", "Camera", "DensifyConfig", "DensifyState", "GaussianModel", "NamedAdam", "NeuralHead",
           "camera_from_c2w", "centred_hybrid_latent", "decode_image", "gaussian_features", "init_from_points",
           "rasterize_features", "refine", "reset_opacity", "scene_extent", "surface_fill", "uncentre", "view_dirs"]
