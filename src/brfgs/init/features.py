"""SfM features of the selected bands: SIFT per band on an 8-bit stretch, pooled, duplicates removed.

For one selected band this is plain SIFT on the band's 8-bit image. For several bands (RGB, CIR,
EFC top-3, all bands) the keypoints of every band are pooled and duplicates (keypoints of
different bands within ``dedupe_px`` pixels of a stronger one with a similar descriptor) removed,
as the paper describes for its "all bands" setting. No pycolmap here: this module is safe to import anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from brfgs.bands.efc import detect_keypoints, make_sift, stretch_to_uint8
from brfgs.init.options import DEFAULT_MAX_FEATURES, SFM_CONTRAST_THRESHOLD  # noqa: F401  (re-exported)

DEDUPE_PX = 1.5
DEDUPE_ANGLE_RAD = 0.5  # descriptors closer than this are the same feature (COLMAP matches up to 0.7)
# SFM_CONTRAST_THRESHOLD: OpenCV contrastThreshold equivalent to COLMAP's SIFT peak threshold (0.02 / 3
# octave layers); Lowe's 0.04 (used for EFC) finds about half as many features.


@dataclass
class ViewFeatures:
    """Features of one view, in pixel coordinates of the loaded image (COLMAP convention: pixel centres at +0.5)."""

    xy: np.ndarray        # [N, 2] float32 (x right, y down)
    scale: np.ndarray     # [N] float32 (SIFT scale, pixels)
    angle_rad: np.ndarray  # [N] float32 orientation
    desc: np.ndarray      # [N, 128] uint8
    n_detected: int       # keypoints after pooling and duplicate removal, before the max_features cap
    band_of: np.ndarray   # [N] int: the selected band that produced each keypoint


def dedupe_keypoints(xy: np.ndarray, response: np.ndarray, radius_px: float = DEDUPE_PX,
                     desc: np.ndarray | None = None, max_angle_rad: float = DEDUPE_ANGLE_RAD) -> np.ndarray:
    """Indices of pooled keypoints kept after removing duplicates.

    Keypoints are visited strongest first; one within ``radius_px`` of a stronger keypoint is a
    duplicate, and when descriptors ``desc`` [N, D] are given only if the two descriptors are also
    alike (angle below ``max_angle_rad``): a blob whose contrast inverts between bands (soil vs
    vegetation in red and near infrared) gives two different features at one place, and keeping
    only the stronger would make the same place look different in two views.
    Returns kept indices in order of decreasing response.
    """
    n = len(xy)
    if n == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((np.arange(n), -np.asarray(response)))  # strongest first, stable
    if radius_px <= 0:
        return order
    pts = np.asarray(xy, np.float64)
    dn = None
    if desc is not None:
        dn = np.asarray(desc, np.float32)
        dn = dn / np.maximum(np.linalg.norm(dn, axis=1, keepdims=True), 1e-12)
    cos_min = np.float32(np.cos(max_angle_rad))

    def alike(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if dn is None:
            return np.ones(len(a), bool)
        return np.einsum("pd,pd->p", dn[a], dn[b]) > cos_min

    # Strongest first, in chunks: a keypoint is a duplicate of an alike kept keypoint within the radius
    # (earlier chunks, via a KD-tree of the kept ones) or of an alike stronger one in its own chunk.
    kept: list[np.ndarray] = []
    kept_all = np.zeros(0, np.int64)
    chunk = 2048
    for start in range(0, n, chunk):
        idx = order[start:start + chunk]
        dup = np.zeros(len(idx), bool)
        if len(kept_all):
            k = min(8, len(kept_all))
            dist, nn = cKDTree(pts[kept_all]).query(pts[idx], k=k, distance_upper_bound=radius_px)
            dist, nn = dist.reshape(len(idx), k), nn.reshape(len(idx), k)
            rows, cols = np.nonzero(np.isfinite(dist))
            if len(rows):
                sim = alike(idx[rows], kept_all[nn[rows, cols]])
                dup[rows[sim]] = True
        pairs = cKDTree(pts[idx]).query_pairs(radius_px, output_type="ndarray")  # i < j: i stronger
        if len(pairs):
            sim = alike(idx[pairs[:, 0]], idx[pairs[:, 1]])
            dup[pairs[sim, 1]] = True
        kept.append(idx[~dup])
        kept_all = np.concatenate(kept)
    return kept_all


def root_sift(desc: np.ndarray) -> np.ndarray:
    """RootSIFT (Arandjelović & Zisserman 2012, COLMAP's default L1_ROOT): sqrt of the L1-normalised
    descriptor, ×512 and clipped to uint8 like COLMAP. [N, 128] → [N, 128] uint8."""
    d = np.asarray(desc, np.float32)
    d = d / np.maximum(d.sum(1, keepdims=True), 1e-12)
    return np.clip(np.rint(np.sqrt(d) * 512.0), 0, 255).astype(np.uint8)


def extract_view_features(cube: np.ndarray, valid: np.ndarray | None = None,
                          max_features: int = DEFAULT_MAX_FEATURES, dedupe_px: float = DEDUPE_PX,
                          sift=None, use_root_sift: bool = True,
                          rect: "Rectification | None" = None) -> ViewFeatures:
    """SIFT features of the band images ``cube`` [H, W, k] (k selected bands), pooled over bands.

    Each band is stretched to 8 bits (:func:`brfgs.bands.efc.stretch_to_uint8`); keypoints
    of all bands are pooled, duplicates removed, and the strongest ``max_features`` kept.
    ``rect``: detect on the nadir-rectified canvas (:func:`nadir_rectification`) and map the keypoints
    back to the image; positions and scales are always in the pixels of ``cube``.
    """
    cube = np.asarray(cube)
    if cube.ndim == 2:
        cube = cube[:, :, None]
    if valid is None:
        valid = np.isfinite(cube).all(-1)
    if rect is not None:
        cube, valid_c = rectify_cube(np.where(valid[:, :, None], cube, np.nan), rect)
        valid = valid_c
    sift = make_sift(contrast_threshold=SFM_CONTRAST_THRESHOLD) if sift is None else sift
    xy, resp, size, ang, desc, band = [], [], [], [], [], []
    for j in range(cube.shape[-1]):
        kp = detect_keypoints(stretch_to_uint8(cube[:, :, j], valid), valid, sift, with_descriptors=True)
        xy.append(kp["xy"])
        resp.append(kp["response"])
        size.append(kp["size"])
        ang.append(kp["angle"])
        desc.append(kp["desc"])
        band.append(np.full(len(kp["xy"]), j))
    xy = np.concatenate(xy)
    resp = np.concatenate(resp)
    desc_all = np.concatenate(desc)
    keep = dedupe_keypoints(xy, resp, dedupe_px if cube.shape[-1] > 1 else 0.0, desc_all)
    n_detected = len(keep)
    keep = keep[:max_features] if max_features else keep
    xy, size = xy[keep].astype(np.float64), np.concatenate(size)[keep] / 2.0
    if rect is not None:  # canvas → image pixels; SIFT scale by the local magnification
        xy = rect.to_image(xy)
        size = size / rect.jacobian_scale(xy)
    return ViewFeatures(
        xy=(xy + 0.5).astype(np.float32),  # first pixel centre at 0 -> COLMAP's 0.5
        scale=size.astype(np.float32),
        angle_rad=np.deg2rad(np.concatenate(ang)[keep]).astype(np.float32),
        desc=root_sift(desc_all[keep]) if use_root_sift else desc_all[keep],
        n_detected=int(n_detected),
        band_of=np.concatenate(band)[keep],
    )


# ----------------------------------------------------------------------------- nadir rectification
# Beyond the paper: oblique views (the 58° ring of the 49-view protocol) see the ground foreshortened
# by cos(θ) along their tilt direction, which SIFT does not undo (it is similarity-invariant only); their
# matches with every other ring are few. Detecting on a copy of the image rotated virtually to nadir
# (a homography that needs only the camera's orientation — gimbal angles or the nominal view angles —
# not its position) makes the ground texture of all views look alike; keypoints are mapped back to the
# original pixels, so SfM still estimates every pose from the images alone.
MAX_RECTIFIED_SIDE = 2.5  # the rectified canvas is at most this many times the image side (the far field of an
#                           oblique view is stretched without bound; it is clipped there)


@dataclass
class Rectification:
    """Homography ``H`` [3, 3] from image pixels to canvas pixels (both OpenCV convention: pixel centres at
    integer coordinates) and the canvas size (w, h)."""

    H: np.ndarray
    size: tuple[int, int]

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """Canvas pixel coordinates [N, 2] → image pixel coordinates [N, 2]."""
        p = np.concatenate([np.asarray(xy, np.float64), np.ones((len(xy), 1))], 1) @ np.linalg.inv(self.H).T
        return p[:, :2] / p[:, 2:3]

    def jacobian_scale(self, xy_img: np.ndarray) -> np.ndarray:
        """sqrt |det J| of the homography at image points [N, 2]: canvas length per image length."""
        p = np.concatenate([np.asarray(xy_img, np.float64), np.ones((len(xy_img), 1))], 1) @ self.H.T
        w = p[:, 2]
        return np.sqrt(np.abs(np.linalg.det(self.H)) / np.abs(w) ** 3)


def nadir_rectification(c2w_gl: np.ndarray, fx: float, fy: float, cx: float, cy: float, w: int, h: int,
                        min_tilt_deg: float = 10.0, max_side: float = MAX_RECTIFIED_SIDE) -> Rectification | None:
    """Homography that turns a camera with orientation ``c2w_gl`` (OpenGL c2w, only its rotation is used)
    into a virtual nadir camera at the same place: a plane z = const then appears without perspective
    foreshortening. Intrinsics in the OpenCV pixel convention (centre of the first pixel at 0) of the image
    the homography is applied to. Scaled so that nothing is down-sampled at the image centre (the smaller
    singular value of the Jacobian there is 1); the canvas is the warped image clipped to ``max_side`` × the
    image size around the warped image centre. None when the optical axis is within ``min_tilt_deg`` of nadir.
    """
    R = np.asarray(c2w_gl, float)[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes → world
    z_cam = R[:, 2]
    tilt = np.degrees(np.arccos(np.clip(-z_cam[2], -1.0, 1.0)))
    if tilt < min_tilt_deg or tilt > 80.0:
        return None
    x_h = R[:, 0] - R[:, 0][2] * np.array([0.0, 0.0, 1.0])  # camera x projected on the horizontal
    if np.linalg.norm(x_h) < 1e-6:
        x_h = np.cross(R[:, 1], [0.0, 0.0, 1.0])
    x_v = x_h / np.linalg.norm(x_h)
    z_v = np.array([0.0, 0.0, -1.0])
    Rv = np.stack([x_v, np.cross(z_v, x_v), z_v], 1)  # virtual camera axes (OpenCV) in world
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    G = Rv.T @ R @ np.linalg.inv(K)  # image pixel → virtual normalised ray
    c = np.array([cx, cy, 1.0])

    def proj(M, pts):
        q = np.concatenate([pts, np.ones((len(pts), 1))], 1) @ M.T
        return q[:, :2] / q[:, 2:3]

    eps = 0.5
    pts = np.array([[cx, cy], [cx + eps, cy], [cx, cy + eps]])
    q = proj(G, pts)
    J = np.stack([(q[1] - q[0]) / eps, (q[2] - q[0]) / eps], 1)
    s = 1.0 / np.linalg.svd(J, compute_uv=False).min()  # canvas pixels per normalised unit
    A = np.diag([s, s, 1.0]) @ G
    corners = proj(A, np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
    mid = proj(A, c[None, :2])[0]
    lo = np.maximum(corners.min(0), mid - 0.5 * max_side * np.array([w, h]))
    hi = np.minimum(corners.max(0), mid + 0.5 * max_side * np.array([w, h]))
    T = np.array([[1, 0, -lo[0]], [0, 1, -lo[1]], [0, 0, 1.0]])
    size = (int(np.ceil(hi[0] - lo[0])) + 1, int(np.ceil(hi[1] - lo[1])) + 1)
    return Rectification(T @ A, size)


def rectify_cube(cube: np.ndarray, rect: Rectification) -> tuple[np.ndarray, np.ndarray]:
    """Warp ``cube`` [H, W, k] onto the rectified canvas (bicubic); returns (canvas [h', w', k], valid [h', w'])."""
    cube = np.asarray(cube, np.float32)
    ok = np.isfinite(cube).all(-1)
    filled = np.where(ok[:, :, None], cube, 0.0).astype(np.float32)
    out = np.stack([cv2.warpPerspective(filled[:, :, j], rect.H, rect.size, flags=cv2.INTER_CUBIC,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                    for j in range(cube.shape[-1])], -1)
    valid = cv2.warpPerspective(ok.astype(np.uint8), rect.H, rect.size, flags=cv2.INTER_NEAREST,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return out, valid
