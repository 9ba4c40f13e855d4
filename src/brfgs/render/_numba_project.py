"""numba kernels of the ``cpu`` rasterizer's projection (3DGS eqs. 5–6) and its backward; the
tile raster is :mod:`brfgs.render._numba_kernels`.

Compiled with ``cache=True`` as the raster kernels (see there). One ``prange`` iteration per
Gaussian, forward and backward. Semantics: see ``brfgs.render._common``.
"""

from __future__ import annotations

import math

from numba import njit, prange

from brfgs.render._common import ALPHA_MIN, EPS2D, EXTENT_ABS, EXTENT_REL, TILE

_FM = {"nsz", "arcp", "contract", "reassoc"}  # fast-math without nnan/ninf/afn


@njit(cache=True, inline="always")
def _rotmat(qw, qx, qy, qz):
    """Rotation matrix of a unit quaternion (wxyz), as 9 scalars row-major."""
    return (1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy),
            2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx),
            2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))


@njit(cache=True, inline="always")
def _to_camera(view, means, i):
    """Camera coordinates (x, y, z) of Gaussian i's mean (view: world-to-camera [4, 4])."""
    mx_ = float(means[i, 0]); my_ = float(means[i, 1]); mz_ = float(means[i, 2])
    x = view[0, 0] * mx_ + view[0, 1] * my_ + view[0, 2] * mz_ + view[0, 3]
    y = view[1, 0] * mx_ + view[1, 1] * my_ + view[1, 2] * mz_ + view[1, 3]
    z = view[2, 0] * mx_ + view[2, 1] * my_ + view[2, 2] * mz_ + view[2, 3]
    return x, y, z


@njit(cache=True, inline="always")
def _mm3(l00, l01, l02, l10, l11, l12, l20, l21, l22, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """3×3 product L·R, 9 scalars row-major; entry (i, j) = L[i,0] R[0,j] + L[i,1] R[1,j] + L[i,2] R[2,j]."""
    return (l00 * r00 + l01 * r10 + l02 * r20, l00 * r01 + l01 * r11 + l02 * r21, l00 * r02 + l01 * r12 + l02 * r22,
            l10 * r00 + l11 * r10 + l12 * r20, l10 * r01 + l11 * r11 + l12 * r21, l10 * r02 + l11 * r12 + l12 * r22,
            l20 * r00 + l21 * r10 + l22 * r20, l20 * r01 + l21 * r11 + l22 * r21, l20 * r02 + l21 * r12 + l22 * r22)


@njit(cache=True, inline="always")
def _gaussian_axes(view, quats, scales, i):
    """Gaussian i: 26 scalars qw, qx, qy, qz (unit), qn (the norm divided by), r00 .. r22 (R row-major),
    s0, s1, s2 (S) and a00 .. a22 (A = Rw · R · S row-major, the camera-space covariance square root)."""
    qw0 = float(quats[i, 0]); qx0 = float(quats[i, 1]); qy0 = float(quats[i, 2]); qz0 = float(quats[i, 3])
    qn = math.sqrt(qw0 * qw0 + qx0 * qx0 + qy0 * qy0 + qz0 * qz0)
    qw = qw0 / qn; qx = qx0 / qn; qy = qy0 / qn; qz = qz0 / qn
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(qw, qx, qy, qz)
    s0 = float(scales[i, 0]); s1 = float(scales[i, 1]); s2 = float(scales[i, 2])
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = _mm3(
        view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2], view[2, 0], view[2, 1], view[2, 2],
        r00 * s0, r01 * s1, r02 * s2, r10 * s0, r11 * s1, r12 * s2, r20 * s0, r21 * s1, r22 * s2)
    return (qw, qx, qy, qz, qn, r00, r01, r02, r10, r11, r12, r20, r21, r22, s0, s1, s2,
            a00, a01, a02, a10, a11, a12, a20, a21, a22)


@njit(cache=True, inline="always")
def _ewa_jacobian(fx, fy, lxn, lxp, lyn, lyp, x, y, z):
    """(rz, xz, yz, txz, tyz, j00, j02, j11, j12): 1/z, x/z and y/z, the same clamped to the bounds lxn ..
    lyp of ``_common.fov_limits``, and the non-zero entries of the EWA Jacobian J (2×3)."""
    rz = 1.0 / z
    xz = x * rz
    yz = y * rz
    txz = min(lxp, max(-lxn, xz))
    tyz = min(lyp, max(-lyn, yz))
    j00 = fx * rz; j02 = -fx * txz * rz
    j11 = fy * rz; j12 = -fy * tyz * rz
    return rz, xz, yz, txz, tyz, j00, j02, j11, j12


@njit(cache=True, inline="always")
def _cov2d(j00, j02, j11, j12, a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """(b00 .. b12, ca, cb, cc, det): B = J · A (2×3), cov2 = B Bᵀ + 0.3 I = [[ca, cb], [cb, cc]], det cov2."""
    b00 = j00 * a00 + j02 * a20; b01 = j00 * a01 + j02 * a21; b02 = j00 * a02 + j02 * a22
    b10 = j11 * a10 + j12 * a20; b11 = j11 * a11 + j12 * a21; b12 = j11 * a12 + j12 * a22
    ca = b00 * b00 + b01 * b01 + b02 * b02 + EPS2D
    cb = b00 * b10 + b01 * b11 + b02 * b12
    cc = b10 * b10 + b11 * b11 + b12 * b12 + EPS2D
    det = ca * cc - cb * cb
    return b00, b01, b02, b10, b11, b12, ca, cb, cc, det


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def project_fwd(means, quats, scales, opac, view, cam, width, height, near, far,
                means2d, conics, depths, radii, rect, visible):
    """EWA projection of every Gaussian.

    means [N,3], quats [N,4], scales [N,3], opac [N]; view [4,4] float64 world-to-camera;
    cam = (fx, fy, cx, cy, lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos) float64 [8].
    Outputs: means2d [N,2], conics [N,3], depths [N], radii [N,2] (half extents, px),
    rect [N,4] int32 tile rectangle (inclusive), visible [N] bool.
    """
    N = means.shape[0]
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lxn, lxp, lyn, lyp = cam[4], cam[5], cam[6], cam[7]
    for i in prange(N):
        x, y, z = _to_camera(view, means, i)
        depths[i] = z
        visible[i] = False
        radii[i, 0] = 0.0
        radii[i, 1] = 0.0
        rect[i, 0] = 0; rect[i, 1] = 0; rect[i, 2] = -1; rect[i, 3] = -1
        means2d[i, 0] = 0.0; means2d[i, 1] = 0.0
        conics[i, 0] = 0.0; conics[i, 1] = 0.0; conics[i, 2] = 0.0
        o = float(opac[i])
        if not (z > near and z < far) or not (o > ALPHA_MIN):
            continue
        a00, a01, a02, a10, a11, a12, a20, a21, a22 = _gaussian_axes(view, quats, scales, i)[17:]  # A only
        rz, _xz, _yz, _txz, _tyz, j00, j02, j11, j12 = _ewa_jacobian(fx, fy, lxn, lxp, lyn, lyp, x, y, z)
        _b00, _b01, _b02, _b10, _b11, _b12, ca, cb, cc, det = _cov2d(
            j00, j02, j11, j12, a00, a01, a02, a10, a11, a12, a20, a21, a22)
        if not (det > 0.0):
            continue
        u = fx * x * rz + cx
        v = fy * y * rz + cy
        smax = math.log(255.0 * o) * (1.0 + EXTENT_REL) + EXTENT_ABS
        rx = math.sqrt(2.0 * smax * ca)
        ry = math.sqrt(2.0 * smax * cc)
        px0 = math.floor(u - rx) - 1.0
        px1 = math.ceil(u + rx)
        py0 = math.floor(v - ry) - 1.0
        py1 = math.ceil(v + ry)
        if px1 < 0.0 or px0 > width - 1 or py1 < 0.0 or py0 > height - 1:
            continue
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        visible[i] = True
        means2d[i, 0] = u
        means2d[i, 1] = v
        conics[i, 0] = cc / det
        conics[i, 1] = -cb / det
        conics[i, 2] = ca / det
        radii[i, 0] = rx
        radii[i, 1] = ry
        rect[i, 0] = int(max(px0, 0.0)) // TILE
        rect[i, 1] = int(max(py0, 0.0)) // TILE
        rect[i, 2] = int(min(px1, width - 1.0)) // TILE
        rect[i, 3] = int(min(py1, height - 1.0)) // TILE


@njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def project_bwd(means, quats, scales, view, cam, visible, v_means2d, v_conics, v_depths,
                v_means, v_quats, v_scales):
    """Backward of :func:`project_fwd` for means, quats and scales (zero for invisible Gaussians).

    v_means2d [N,2], v_conics [N,3], v_depths [N] → v_means [N,3], v_quats [N,4], v_scales [N,3].
    The depth gradient flows for every Gaussian in front of the near plane that is visible.
    """
    N = means.shape[0]
    fx, fy = cam[0], cam[1]
    lxn, lxp, lyn, lyp = cam[4], cam[5], cam[6], cam[7]
    for i in prange(N):
        for k in range(3):
            v_means[i, k] = 0.0
            v_scales[i, k] = 0.0
        for k in range(4):
            v_quats[i, k] = 0.0
        if not visible[i]:
            continue
        x, y, z = _to_camera(view, means, i)
        (qw, qx, qy, qz, qn, r00, r01, r02, r10, r11, r12, r20, r21, r22, s0, s1, s2,
         a00, a01, a02, a10, a11, a12, a20, a21, a22) = _gaussian_axes(view, quats, scales, i)
        rz, xz, yz, txz, tyz, j00, j02, j11, j12 = _ewa_jacobian(fx, fy, lxn, lxp, lyn, lyp, x, y, z)
        x_free = (xz >= -lxn) and (xz <= lxp)
        y_free = (yz >= -lyn) and (yz <= lyp)
        b00, b01, b02, b10, b11, b12, ca, cb, cc, det = _cov2d(
            j00, j02, j11, j12, a00, a01, a02, a10, a11, a12, a20, a21, a22)
        X00 = cc / det; X01 = -cb / det; X11 = ca / det
        # Symmetric gradient of the conic matrix X: off-diagonal entries get half of dL/db.
        G00 = float(v_conics[i, 0]); G01 = 0.5 * float(v_conics[i, 1]); G11 = float(v_conics[i, 2])
        # dL/dcov2 = -X G X
        t00 = G00 * X00 + G01 * X01; t01 = G00 * X01 + G01 * X11
        t10 = G01 * X00 + G11 * X01; t11 = G01 * X01 + G11 * X11
        H00 = -(X00 * t00 + X01 * t10)
        H01 = -(X00 * t01 + X01 * t11)
        H11 = -(X01 * t01 + X11 * t11)
        # cov2 = B Bᵀ → dL/dB = 2 H B
        gb00 = 2.0 * (H00 * b00 + H01 * b10); gb01 = 2.0 * (H00 * b01 + H01 * b11); gb02 = 2.0 * (H00 * b02 + H01 * b12)
        gb10 = 2.0 * (H01 * b00 + H11 * b10); gb11 = 2.0 * (H01 * b01 + H11 * b11); gb12 = 2.0 * (H01 * b02 + H11 * b12)
        # B = J A → dL/dJ = gB Aᵀ (only the 4 non-zero entries), dL/dA = Jᵀ gB
        gj00 = gb00 * a00 + gb01 * a01 + gb02 * a02
        gj02 = gb00 * a20 + gb01 * a21 + gb02 * a22
        gj11 = gb10 * a10 + gb11 * a11 + gb12 * a12
        gj12 = gb10 * a20 + gb11 * a21 + gb12 * a22
        ga00 = j00 * gb00; ga01 = j00 * gb01; ga02 = j00 * gb02
        ga10 = j11 * gb10; ga11 = j11 * gb11; ga12 = j11 * gb12
        ga20 = j02 * gb00 + j12 * gb10; ga21 = j02 * gb01 + j12 * gb11; ga22 = j02 * gb02 + j12 * gb12
        # A = Rw M → dL/dM = Rwᵀ gA
        gm00, gm01, gm02, gm10, gm11, gm12, gm20, gm21, gm22 = _mm3(
            view[0, 0], view[1, 0], view[2, 0], view[0, 1], view[1, 1], view[2, 1], view[0, 2], view[1, 2],
            view[2, 2], ga00, ga01, ga02, ga10, ga11, ga12, ga20, ga21, ga22)
        # M = R S
        v_scales[i, 0] = gm00 * r00 + gm10 * r10 + gm20 * r20
        v_scales[i, 1] = gm01 * r01 + gm11 * r11 + gm21 * r21
        v_scales[i, 2] = gm02 * r02 + gm12 * r12 + gm22 * r22
        g00 = gm00 * s0; g01 = gm01 * s1; g02 = gm02 * s2
        g10 = gm10 * s0; g11 = gm11 * s1; g12 = gm12 * s2
        g20 = gm20 * s0; g21 = gm21 * s1; g22 = gm22 * s2
        # R(q) → dL/dq (unit q), then through q = q0/|q0|
        gw = 2.0 * (-qz * g01 + qy * g02 + qz * g10 - qx * g12 - qy * g20 + qx * g21)
        gx = 2.0 * (qy * g01 + qz * g02 + qy * g10 - 2.0 * qx * g11 - qw * g12 + qz * g20 + qw * g21 - 2.0 * qx * g22)
        gy = 2.0 * (-2.0 * qy * g00 + qx * g01 + qw * g02 + qx * g10 + qz * g12 - qw * g20 + qz * g21 - 2.0 * qy * g22)
        gz = 2.0 * (-2.0 * qz * g00 - qw * g01 + qx * g02 + qw * g10 - 2.0 * qz * g11 + qy * g12 + qx * g20 + qy * g21)
        dot = qw * gw + qx * gx + qy * gy + qz * gz
        v_quats[i, 0] = (gw - qw * dot) / qn
        v_quats[i, 1] = (gx - qx * dot) / qn
        v_quats[i, 2] = (gy - qy * dot) / qn
        v_quats[i, 3] = (gz - qz * dot) / qn
        # camera-space position gradient: from means2d, depth and the Jacobian
        vu = float(v_means2d[i, 0]); vv = float(v_means2d[i, 1])
        gxc = vu * fx * rz
        gyc = vv * fy * rz
        gzc = -(vu * fx * x + vv * fy * y) * rz * rz + float(v_depths[i])
        # J00 = fx/z, J11 = fy/z, J02 = -fx·tx/z², J12 = -fy·ty/z² with tx = z·clamp(x/z)
        gzc += -(gj00 * fx + gj11 * fy) * rz * rz
        if x_free:   # tx = x: J02 = -fx x / z²
            gxc += gj02 * (-fx * rz * rz)
            gzc += gj02 * (2.0 * fx * x * rz * rz * rz)
        else:        # tx = z·lim: J02 = -fx lim / z
            gzc += gj02 * (fx * txz * rz * rz)
        if y_free:
            gyc += gj12 * (-fy * rz * rz)
            gzc += gj12 * (2.0 * fy * y * rz * rz * rz)
        else:
            gzc += gj12 * (fy * tyz * rz * rz)
        for k in range(3):
            v_means[i, k] = view[0, k] * gxc + view[1, k] * gyc + view[2, k] * gzc
