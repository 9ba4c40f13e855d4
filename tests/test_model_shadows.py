"""Sun visibility from the model's own geometry (brfgs.model.shadows) against the closed form of a
limit case: an opaque square roof of Gaussians above an opaque ground casts the square, shifted by
h·tan θ_s away from the sun, onto the ground; no roof, no shadow; a view's visibility map shows the
shadow where the ground is seen."""

import math

import numpy as np
import pytest
import torch

from brfgs.analysis.bench import synthetic_model
from brfgs.data.angles import direction_from_angles_deg
from brfgs.data.cameras import Intrinsics, look_at_c2w, project_points
from brfgs.model import camera_from_intrinsics
from brfgs.model.shadows import gaussian_sun_visibility, sun_camera
from brfgs.model.view import sun_visibility_map

ROOF_Z_M, ROOF_HALF_M = 5.0, 4.0


def _roof_model(with_roof: bool = True, n_side: int = 40):
    """Flat opaque Gaussians on a 1 m grid at z = 0 (40 × 40 m) and a 0.5 m grid at z = 5 m over
    |x|, |y| ≤ 4 m (the roof)."""
    g = np.arange(n_side, dtype=np.float32) - (n_side - 1) / 2
    X, Y = np.meshgrid(g, g)
    ground = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size, np.float32)], 1)
    r = np.arange(-ROOF_HALF_M + 0.25, ROOF_HALF_M, 0.5, dtype=np.float32)
    RX, RY = np.meshgrid(r, r)
    roof = np.stack([RX.ravel(), RY.ravel(), np.full(RX.size, ROOF_Z_M, np.float32)], 1)
    means = np.concatenate([ground, roof]) if with_roof else ground
    scale = np.concatenate([np.full(len(ground), 0.6), np.full(len(roof) if with_roof else 0, 0.3)]).astype(np.float32)
    tm = synthetic_model(n_gaussians=len(means))
    p = tm.gaussians.params
    p["means"] = torch.from_numpy(means)
    p["log_scales"] = torch.log(torch.from_numpy(np.stack([scale, scale, np.full_like(scale, 0.02)], 1)))
    p["quats"] = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(len(means), 1)
    p["opacity_logits"] = torch.full((len(means),), math.log(0.99 / 0.01))
    return tm, len(ground), ground


def _in_shadow(ground: np.ndarray, sun_z: float, sun_a: float, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(surely shadowed, surely lit) ground points: the sun ray from the point meets the roof's plane
    inside the square shrunk / grown by ``margin_m``."""
    w = direction_from_angles_deg(sun_z, sun_a)
    hit = ground[:, :2] + (ROOF_Z_M / w[2]) * w[:2]                      # [n, 2] where the ray crosses z = 5 m
    inside = np.abs(hit).max(1)
    return inside < ROOF_HALF_M - margin_m, inside > ROOF_HALF_M + margin_m


@pytest.mark.parametrize("sun", [(30.0, 90.0), (50.0, 220.0), (0.0, 0.0)])
def test_the_roof_shadow_falls_where_the_closed_form_puts_it(sun):
    tm, n_ground, ground = _roof_model()
    v = gaussian_sun_visibility(tm, *sun, backend="torch").numpy()
    shade, lit = _in_shadow(ground, *sun, margin_m=1.5)  # the splats reach 3σ = 0.9 m past the roof grid
    assert shade.sum() >= 16 and lit.sum() >= 500
    assert (v[:n_ground][shade] < 0.05).all(), np.sort(v[:n_ground][shade])[-5:]
    assert (v[:n_ground][lit] > 0.95).all(), np.sort(v[:n_ground][lit])[:5]
    assert (v[n_ground:] > 0.95).all()                                  # the roof itself is lit


def test_without_occluders_everything_is_lit():
    tm, n_ground, _ = _roof_model(with_roof=False)
    assert (gaussian_sun_visibility(tm, 60.0, 300.0, backend="torch") > 0.99).all()


def test_the_sun_camera_looks_along_the_sun_and_holds_the_scene():
    tm, _, _ = _roof_model()
    means = tm.frozen()["means"]
    w = torch.as_tensor(direction_from_angles_deg(40.0, 130.0), dtype=torch.float32)
    cam = sun_camera(means, w, 256)
    c2w = np.linalg.inv(cam.viewmat.double().numpy())                   # OpenCV camera-to-world
    axis = c2w[:3, 2]                                                   # optical axis (OpenCV +z)
    assert np.allclose(axis, -w.double().numpy(), atol=1e-6)           # looking along the sun's rays
    uv = (cam.K.double().numpy() @ (cam.viewmat.double().numpy()[:3, :3] @ means.double().numpy().T
                                    + cam.viewmat.double().numpy()[:3, 3:])).T
    uv = uv[:, :2] / uv[:, 2:]
    inside = ((uv >= 0) & (uv <= 256)).all(1)
    assert inside.mean() >= 0.995 and np.abs(uv - 128).max() < 0.6 * 256  # the far 0.2 % just outside


def test_a_view_map_shows_the_shadow_on_the_ground():
    tm, _, _ = _roof_model()
    sun = (45.0, 90.0)                                                  # from the east: the shadow lies west
    intr = Intrinsics(fl_x=80.0, fl_y=80.0, cx=32.0, cy=32.0, w=64, h=64)
    c2w = look_at_c2w(np.array([0.0, 0.0, 60.0]), np.zeros(3))
    cam = camera_from_intrinsics(c2w, intr)
    m = sun_visibility_map(tm, cam, gaussian_sun_visibility(tm, *sun, backend="torch"), backend="torch")
    pts = np.array([[-ROOF_Z_M - 1.0, 0.0, 0.0], [ROOF_HALF_M + 3.0, 0.0, 0.0], [0.0, 0.0, ROOF_Z_M]])
    uv, _ = project_points(pts, c2w, intr)
    vals = [float(m[int(r), int(c)]) for c, r in uv]
    assert vals[0] < 0.05 and vals[1] > 0.95 and vals[2] > 0.95, vals   # ground west of the roof, east, roof
