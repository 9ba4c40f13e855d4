"""Where a click lands and what the index modes show: the ray's median-opacity depth (checked against
the blending weights of each Gaussian, read from the rasterizer one Gaussian per channel), clicks on
faint surfaces, the sky, and the background mask of the index modes."""

import math

import numpy as np
import pytest
import torch

from brfgs.analysis.bench import synthetic_model
from brfgs.data.cameras import look_at_c2w, project_points
from brfgs.model import camera_from_intrinsics, render
from brfgs.model.rendering import frustum_subset
from brfgs.data.cameras import Intrinsics
from brfgs.viewer.frames import SURFACE_MIN_ALPHA, parse_mode, render_frame
from brfgs.viewer.roi import click_ray, surface_hit


def _layered_model(opacity_ground: float, opacity_top: float = 0.0, top_z_m: float = 4.0, n_side: int = 24):
    """Flat Gaussians on a 1 m grid at z = 0 (opacity ``opacity_ground``) and, when ``opacity_top`` > 0,
    a second grid at ``top_z_m`` (a faint layer above the ground)."""
    layers = [(0.0, opacity_ground)] + ([(top_z_m, opacity_top)] if opacity_top > 0 else [])
    tm = synthetic_model(n_gaussians=n_side * n_side * len(layers))
    g = (np.arange(n_side) - (n_side - 1) / 2).astype(np.float32)
    X, Y = np.meshgrid(g, g)
    means = np.concatenate([np.stack([X.ravel(), Y.ravel(), np.full(X.size, z, np.float32)], 1) for z, _ in layers])
    opac = np.concatenate([np.full(X.size, o, np.float32) for _, o in layers])
    p = tm.gaussians.params
    p["means"] = torch.from_numpy(means)
    p["log_scales"] = torch.log(torch.tensor([[0.6, 0.6, 0.02]])).repeat(len(means), 1)
    p["quats"] = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(len(means), 1)
    p["opacity_logits"] = torch.logit(torch.from_numpy(opac))
    return tm


def _weights_reference(tm, c2w, intr, x, y) -> tuple[np.ndarray, np.ndarray]:
    """(depth along the optical axis [n], blending weight [n]) of each Gaussian that can touch the
    pixel at (x, y) ∈ [0, 1]²: that pixel rendered with one channel per Gaussian (identity features)."""
    one = Intrinsics(intr.fl_x, intr.fl_y, intr.cx - x * intr.w + 0.5, intr.cy - y * intr.h + 0.5, 1, 1)
    cam = camera_from_intrinsics(c2w, one)
    means = tm.frozen()["means"]
    sub = frustum_subset(means, tm.frozen()["max_scale"], cam)
    col = torch.full((means.shape[0],), -1, dtype=torch.long)
    col[sub] = torch.arange(sub.numel())

    def one_hot(idx, omega_o):
        return torch.nn.functional.one_hot(col[idx], sub.numel()).float()

    w = render(tm, cam, features=one_hot).image.reshape(-1).numpy().astype(np.float64)
    z = ((means[sub].double() - torch.as_tensor(c2w[:3, 3])) @ torch.as_tensor(-c2w[:3, 2])).numpy()
    return z, w


def _median_depth(z: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(z, kind="stable")
    acc = np.cumsum(w[order])
    return float(z[order][np.argmax(acc >= 0.5 * acc[-1])])


@pytest.mark.parametrize("zenith_deg", [0.0, 35.0])
def test_hit_is_the_median_depth_of_the_blending_weights(zenith_deg):
    tm = synthetic_model(n_gaussians=3000)
    centre = np.array([3.0, -2.0, 0.0])
    eye = centre + 120.0 * np.array([math.sin(math.radians(zenith_deg)), 0.0, math.cos(math.radians(zenith_deg))])
    c2w, f = look_at_c2w(eye, centre), 300.0
    intr = Intrinsics(f, f, 64.0, 64.0, 128, 128)
    alpha = render(tm, camera_from_intrinsics(c2w, intr), decode=False).alpha
    picks = []
    for lo, hi in [(0.0, 0.05), (0.12, 0.3), (0.3, 0.6), (0.6, 0.9), (0.95, 1.0)]:  # one pixel per opacity range
        ii, jj = np.nonzero((alpha >= lo) & (alpha < hi))
        assert ii.size, (lo, hi)
        picks.append((ii[ii.size // 2], jj[ii.size // 2]))
    for i, j in picks:
        x, y = (j + 0.5) / intr.w, (i + 0.5) / intr.h
        z, w = _weights_reference(tm, c2w, intr, x, y)
        # the pixel rendered alone: the same pixel as the frame's, but the rasterizer bounds the
        # projection's Jacobian by the image's field of view (3DGS), which is the pixel's here
        assert w.sum() == pytest.approx(alpha[i, j], abs=0.01)
        p = surface_hit(tm, c2w, intr, x, y)
        if w.sum() < SURFACE_MIN_ALPHA:
            assert p is None
            continue
        o, d = click_ray(c2w, intr, x, y)
        expect = o + _median_depth(z, w) / float(d @ -c2w[:3, 2]) * d
        assert p is not None and np.allclose(p, expect, atol=1e-4)
        uv, depth = project_points(p[None], c2w, intr)  # on the clicked pixel's ray
        assert np.allclose(uv[0], [j + 0.5, i + 0.5], atol=1e-6) and depth[0] == pytest.approx(_median_depth(z, w))


def test_a_faint_surface_is_hit_at_its_median_depth_not_its_mean_depth():
    """Ground of opacity 0.2 under a faint layer 4 m above it: total opacity below 0.5 (the former
    rule hit nothing), the hit on the ground (z = 0), where the mean (rendered) depth is not."""
    tm = _layered_model(0.2, opacity_top=0.03)
    eye, f = np.array([0.3, 0.2, 60.0]), 400.0
    c2w = look_at_c2w(eye, np.array([0.3, 0.2, 0.0]), up=np.array([0.0, 1.0, 0.0]))
    intr = Intrinsics(f, f, 32.0, 32.0, 64, 64)
    view = render(tm, camera_from_intrinsics(c2w, intr), decode=False)
    assert 0.1 < view.alpha[32, 32] < 0.5
    p = surface_hit(tm, c2w, intr, 32.5 / 64, 32.5 / 64)
    assert p is not None and abs(p[2]) < 1e-3
    mean_depth_point_z = eye[2] - view.depth[32, 32]  # straight down: height of the rendered (mean) depth
    assert mean_depth_point_z > 0.2  # the expected depth lies between the layers


def _looking(eye, direction):
    eye = np.asarray(eye, float)
    return look_at_c2w(eye, eye + np.asarray(direction, float), up=np.array([0.0, 1.0, 0.0])), \
        Intrinsics(300.0, 300.0, 32.0, 32.0, 64, 64)


def test_a_ray_into_the_sky_hits_nothing():
    tm = _layered_model(0.9)
    for direction in ([0.0, 0.3, 1.0], [1.0, 0.0, 0.01]):  # upwards; along the horizon above the ground
        assert surface_hit(tm, *_looking([0.0, 0.0, 5.0], direction), 0.5, 0.5) is None
    p = surface_hit(tm, *_looking([0.0, 0.0, 5.0], [0.0, 0.0, -1.0]), 0.5, 0.5)
    assert p is not None and abs(p[2]) < 1e-3


def test_an_almost_transparent_ground_is_not_hit():
    tm = _layered_model(0.02)
    assert surface_hit(tm, *_looking([0.0, 0.0, 30.0], [0.0, 0.0, -1.0]), 0.5, 0.5) is None


def test_index_modes_mask_the_background():
    """A view over the edge of the ground: where the accumulated opacity is below SURFACE_MIN_ALPHA the
    index frame is black (the learned background has no index), on the ground it is the colour map."""
    tm = _layered_model(0.9, n_side=16)
    c2w = look_at_c2w(np.array([0.0, -30.0, 20.0]), np.array([0.0, 10.0, 0.0]))
    intr = Intrinsics(60.0, 60.0, 32.0, 32.0, 64, 64)
    view = render(tm, camera_from_intrinsics(c2w, intr))
    sky = view.alpha < SURFACE_MIN_ALPHA
    assert 0.1 < sky.mean() < 0.9
    rgb = render_frame(tm, c2w, intr, parse_mode("index:(b860-b650)/(b860+b650)")).rgb
    assert (rgb[sky] == 0).all()
    assert (rgb[view.alpha > 0.5].max(-1) > 0).all()
    cir = render_frame(tm, c2w, intr, parse_mode("cir")).rgb  # the CIR still shows the background
    assert cir[sky].max() > 0
