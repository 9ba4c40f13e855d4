"""A linear spectral basis B -> d -> B: the affine decoder D(z) = W z + b beside the autoencoder (eq. 9).

:class:`LinearBasis` has the interface the rest of the code uses for
:class:`brfgs.spectral.autoencoder.SpectralAutoencoder` (``encode``, ``decode``, ``forward``,
``n_bands``, ``latent_dim``, ``describe`` / ``from_description``, :func:`linear_basis_state` /
:func:`linear_basis_from_state`). Decoding is one matrix product per pixel, in reflectance units:

    D(z) = W z + b,   W [B, d], b [B].

Because D is affine, eq. 12's rendered spectrum D(z_iso + Σ_c K_c z_c) = (W z_iso + b) + Σ_c K_c W z_c:
every band's BRF is the MODIS kernel-driven model (plus the specular lobe) with the per-band weights
f_iso = W z_iso + b, f_vol = W z_vol, f_geo = W z_geo (f_spec = W z_spec) of each Gaussian, and
blending latents then decoding equals decoding each Gaussian then blending spectra (the blending
weights and the background's (1 − α) sum to one).

Fitting (:func:`fit_linear_basis`) is closed form: the noise-weighted principal components of the
training pixels. With x_n [B] the pixels and σ_b the per-band (dark-frame) noise, the basis minimises
the whitened residual Σ_n Σ_b ((x_nb − (W z_n + b)_b) / σ_b)², the maximum-likelihood rank-d fit under
independent Gaussian noise of standard deviation σ_b per band. Its solution (Eckart–Young):

    b = mean_n x_n,  Y = (X − b) Σ^{-1/2}  (Σ = diag σ_b²),  Y = U S Vᵀ (SVD),
    W = Σ^{1/2} V_d diag(s),  s_j = S_j / sqrt(N − 1)

(V_d the first d right singular vectors: the whitened PCA, un-whitened). Each latent component is
scaled to unit variance over the training pixels (as the autoencoder standardises its input) and the
sign of each basis vector fixed so that its largest-magnitude entry is positive (a deterministic
result). Encoding is the weighted least-squares projection (the σ-weighted pseudo-inverse)

    z = (Wᵀ Σ^{-1} W)^{-1} Wᵀ Σ^{-1} (x − b),

which for the fitted basis is z_j = v_jᵀ Σ^{-1/2} (x − b) / s_j, the standardised PCA scores; it stays
the weighted projection when W changes (fine-tuning in training).
"""

from __future__ import annotations

import json

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["LinearBasis", "fit_linear_basis", "linear_basis_state", "linear_basis_from_state"]

# σ_b below this fraction of the median positive σ_b is raised to it (a band without measured noise
# must not get an unbounded weight)
SIGMA_FLOOR_REL = 1e-3
# latent scales below this fraction of the first component's are raised to it (components beyond the
# data's rank keep a usable, tiny basis vector)
SCALE_FLOOR_REL = 1e-6


class LinearBasis(nn.Module):
    """Affine spectral decoder D(z) = W z + b (see the module docstring); forward returns
    (reconstruction [N, B], z [N, d]) as the autoencoder's does."""

    def __init__(self, n_bands: int, latent_dim: int = 16):
        super().__init__()
        if not 1 <= int(latent_dim) <= int(n_bands):
            raise ValueError(f"latent_dim must be in 1..{n_bands} (the bands), got {latent_dim}")
        self.n_bands = int(n_bands)
        self.latent_dim = int(latent_dim)
        self.weight = nn.Parameter(torch.zeros(self.n_bands, self.latent_dim))  # W [B, d]
        self.bias = nn.Parameter(torch.zeros(self.n_bands))  # b [B]
        self.register_buffer("noise_sigma", torch.ones(self.n_bands))  # σ_b [B] of the encoder's weighting

    def _wb(self, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
        w, b = self.weight, self.bias
        return (w, b) if w.dtype == dtype else (w.to(dtype), b.to(dtype))

    def decode(self, z: Tensor) -> Tensor:
        """Latent ``[..., d]`` -> reflectance ``[..., B]``: W z + b (differentiable in z, W and b)."""
        return F.linear(z, *self._wb(z.dtype))

    def decode_weights(self, z: Tensor) -> Tensor:
        """W z ``[..., B]`` of latents ``[..., d]`` without the offset b: the per-band weight of a kernel
        term whose latent coefficient is z (f_vol = W z_vol, ...)."""
        return F.linear(z, self._wb(z.dtype)[0])

    def encoder_matrix(self, dtype: torch.dtype = torch.float32) -> Tensor:
        """P [B, d] with z = (x − b) P: the σ-weighted pseudo-inverse Σ^{-1} W (Wᵀ Σ^{-1} W)^{-1},
        computed in float64."""
        w = self.weight.detach().double()
        wi = w / (self.noise_sigma.double() ** 2)[:, None]  # Σ^{-1} W [B, d]
        return torch.linalg.solve(w.T @ wi, wi.T).T.to(dtype)

    def encode(self, r: Tensor) -> Tensor:
        """Reflectance ``[..., B]`` -> latent ``[..., d]``: the weighted least-squares projection."""
        return (r - self.bias.detach().to(r.dtype)) @ self.encoder_matrix(r.dtype)

    def forward(self, r: Tensor) -> tuple[Tensor, Tensor]:
        z = self.encode(r)
        return self.decode(z), z

    def describe(self) -> dict:
        """JSON-ready description (stored in model files)."""
        return {"n_bands": self.n_bands, "latent_dim": self.latent_dim}

    @classmethod
    def from_description(cls, desc: dict) -> "LinearBasis":
        return cls(desc["n_bands"], desc["latent_dim"])


def _noise_weights(sigma_b, n_bands: int) -> np.ndarray:
    """σ_b [B] (float64) with non-finite or tiny values raised to SIGMA_FLOOR_REL × the median positive σ;
    ones when ``sigma_b`` is None or holds no positive value."""
    if sigma_b is None:
        return np.ones(n_bands)
    s = np.asarray(sigma_b, np.float64).reshape(-1)
    if s.shape != (n_bands,):
        raise ValueError(f"sigma_b has {s.size} values for {n_bands} bands")
    pos = s[np.isfinite(s) & (s > 0)]
    if pos.size == 0:
        return np.ones(n_bands)
    return np.maximum(np.where(np.isfinite(s), s, 0.0), SIGMA_FLOOR_REL * float(np.median(pos)))


def _orthonormal_columns(v: np.ndarray, d: int) -> np.ndarray:
    """v [B, k] (orthonormal columns, k ≤ d) completed to d orthonormal columns (deterministic)."""
    if v.shape[1] >= d:
        return v[:, :d]
    q, _ = np.linalg.qr(np.concatenate([v, np.eye(v.shape[0])], 1))
    q = q[:, :d].copy()
    q[:, : v.shape[1]] = v  # QR may flip the given columns' signs: keep them as given
    return q


def fit_linear_basis(pixels: np.ndarray, latent_dim: int = 16, sigma_b=None, *, seed: int = 0,
                     max_pixels: int | None = None) -> LinearBasis:
    """The noise-weighted PCA basis of spectra ``pixels`` [N, B] (closed form, module docstring).

    ``sigma_b`` [B]: per-band noise (the scene's dark-frame σ_b) whitening the fit, None for unit
    weights; ``max_pixels``: fit on that many pixels drawn with ``seed`` when there are more (None: all).
    Deterministic: the same pixels give the same basis."""
    x = np.asarray(pixels, np.float64)
    if x.ndim != 2 or x.shape[0] < 1:
        raise ValueError(f"pixels must be [N, B] with N >= 1, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("pixels must be finite")
    if max_pixels is not None and x.shape[0] > max_pixels:
        x = x[np.sort(np.random.default_rng(seed).choice(x.shape[0], max_pixels, replace=False))]
    n, n_bands = x.shape
    d = int(latent_dim)
    basis = LinearBasis(n_bands, d)
    sigma = _noise_weights(sigma_b, n_bands)
    mean = x.mean(0)
    _, s, vt = np.linalg.svd((x - mean) / sigma, full_matrices=False)  # whitened, centred
    k = min(d, int(np.sum(s > s[0] * 1e-12))) if s.size and s[0] > 0 else 0
    v = _orthonormal_columns(vt[:k].T, d)  # [B, d]
    big = np.argmax(np.abs(v), 0)
    v = v * np.where(v[big, np.arange(d)] < 0, -1.0, 1.0)  # sign: largest-magnitude entry positive
    scale = np.zeros(d)
    scale[:k] = s[:k] / np.sqrt(max(n - 1, 1))
    first = scale[0] if k else 1.0
    scale = np.maximum(scale, SCALE_FLOOR_REL * first)
    with torch.no_grad():
        basis.weight.copy_(torch.from_numpy(sigma[:, None] * v * scale[None, :]))
        basis.bias.copy_(torch.from_numpy(mean))
        basis.noise_sigma.copy_(torch.from_numpy(sigma))
    return basis.eval()


def linear_basis_state(basis: LinearBasis, prefix: str = "decoder.") -> tuple[dict, dict]:
    """(tensors, metadata) for a safetensors file: W, b and σ_b under ``prefix`` and the description."""
    tensors = {prefix + k: v.detach().contiguous().clone() for k, v in basis.state_dict().items()}
    return tensors, {"linear_basis": json.dumps(basis.describe())}


def linear_basis_from_state(tensors: dict, meta: dict, prefix: str = "decoder.") -> LinearBasis:
    """Inverse of :func:`linear_basis_state`."""
    basis = LinearBasis.from_description(json.loads(meta["linear_basis"]))
    basis.load_state_dict({k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)})
    return basis.eval()
