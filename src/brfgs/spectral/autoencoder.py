"""1-D convolutional spectral autoencoder B -> d -> B (paper eq. 9, Fig. 3a).

The encoder E_phi maps a reflectance spectrum r [B] to a latent z [d]; the decoder
D_phi maps z back to r. Spectra are standardised per band (mean/std of the training
pixels, stored as buffers) before encoding, and the decoder returns reflectance units.

Architecture (small on purpose: it decodes every rendered pixel during training):
- encoder: Conv1d(1->c1, k7, s2) GELU Conv1d(c1->c2, k5, s2) GELU flatten Linear -> d
- decoder: a linear path Linear(d -> B) (a PCA-like basis that trains fast and keeps the
  decoder well behaved on blended latents) plus a convolutional residual
  Linear(d -> c2*L) GELU ConvTranspose1d x2 -> B.

Training (:func:`train_autoencoder`) uses pixels sampled from the training images with
L1 + spectral-angle loss; :func:`evaluate_autoencoder` reports reconstruction SAM and
RMSE on test pixels so users see what the compression costs.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm


@dataclass
class AutoencoderConfig:
    """Options of the spectral autoencoder (latent size d and its training)."""

    latent_dim: int = 16  # d <= 32; 16 chosen by the experiment in docs/results.md
    channels1: int = 8
    channels2: int = 16
    steps: int = 1500
    batch_size: int = 2048
    lr: float = 3e-3
    sam_weight: float = 0.5  # loss = L1 (reflectance) + sam_weight * mean spectral angle
    max_pixels: int = 200_000  # pixels sampled from the training images
    seed: int = 0


class SpectralAutoencoder(nn.Module):
    """B -> d -> B 1-D conv autoencoder; forward returns (reconstruction [N,B], z [N,d])."""

    def __init__(self, n_bands: int, latent_dim: int = 16, channels1: int = 8, channels2: int = 16):
        super().__init__()
        if not 1 <= latent_dim <= 32:
            raise ValueError(f"latent_dim must be in 1..32, got {latent_dim}")
        self.n_bands = int(n_bands)
        self.latent_dim = int(latent_dim)
        self.channels1 = int(channels1)
        self.channels2 = int(channels2)
        B = self.n_bands
        L1 = (B + 2 * 3 - 7) // 2 + 1
        L2 = (L1 + 2 * 2 - 5) // 2 + 1
        self._L2 = L2
        self.register_buffer("band_mean", torch.zeros(B))
        self.register_buffer("band_std", torch.ones(B))
        self.enc_conv1 = nn.Conv1d(1, channels1, 7, stride=2, padding=3)
        self.enc_conv2 = nn.Conv1d(channels1, channels2, 5, stride=2, padding=2)
        self.enc_fc = nn.Linear(channels2 * L2, latent_dim)
        self.dec_lin = nn.Linear(latent_dim, B)
        self.dec_fc = nn.Linear(latent_dim, channels2 * L2)
        self.dec_up1 = nn.ConvTranspose1d(channels2, channels1, 4, stride=2, padding=1)
        self.dec_up2 = nn.ConvTranspose1d(channels1, 1, 4, stride=2, padding=1)
        nn.init.zeros_(self.dec_up2.weight)  # start as the linear decoder
        nn.init.zeros_(self.dec_up2.bias)

    # -- normalisation -------------------------------------------------------
    def set_normalisation(self, pixels: torch.Tensor) -> None:
        """Set per-band mean/std from training spectra ``pixels [N, B]``."""
        self.band_mean.copy_(pixels.mean(0))
        self.band_std.copy_(pixels.std(0).clamp_min(1e-4))

    # -- maps ------------------------------------------------------------------
    def encode(self, r: torch.Tensor) -> torch.Tensor:
        """Reflectance ``[..., B]`` -> latent ``[..., d]`` (eq. 9)."""
        shp = r.shape[:-1]
        x = ((r.reshape(-1, self.n_bands) - self.band_mean) / self.band_std)[:, None, :]  # [N,1,B]
        x = F.gelu(self.enc_conv1(x))
        x = F.gelu(self.enc_conv2(x))
        z = self.enc_fc(x.flatten(1))
        return z.reshape(*shp, self.latent_dim)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Latent ``[..., d]`` -> reflectance ``[..., B]`` (eq. 13)."""
        shp = z.shape[:-1]
        z2 = z.reshape(-1, self.latent_dim)
        lin = self.dec_lin(z2)  # [N,B]
        h = F.gelu(self.dec_fc(z2)).reshape(-1, self.channels2, self._L2)
        h = F.gelu(self.dec_up1(h))
        h = self.dec_up2(h)[:, 0]  # [N, 4*L2]
        if h.shape[1] >= self.n_bands:
            h = h[:, : self.n_bands]
        else:
            h = F.interpolate(h[:, None], size=self.n_bands, mode="linear", align_corners=False)[:, 0]
        x = lin + h
        r = x * self.band_std + self.band_mean
        return r.reshape(*shp, self.n_bands)

    def forward(self, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.encode(r)
        return self.decode(z), z

    def describe(self) -> dict:
        """JSON-ready architecture description (stored in checkpoints)."""
        return {
            "n_bands": self.n_bands,
            "latent_dim": self.latent_dim,
            "channels1": self.channels1,
            "channels2": self.channels2,
        }

    @classmethod
    def from_description(cls, desc: dict) -> "SpectralAutoencoder":
        return cls(desc["n_bands"], desc["latent_dim"], desc["channels1"], desc["channels2"])


def spectral_angle_torch(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Spectral angle (radians) of ``[..., B]`` tensors -> ``[...]`` (differentiable)."""
    cos = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(eps)
    return torch.acos(cos.clamp(-1 + 1e-6, 1 - 1e-6))


def autoencoder_loss(recon: torch.Tensor, target: torch.Tensor, sam_weight: float) -> torch.Tensor:
    """L1 + sam_weight * mean spectral angle over pixels ``[N, B]``."""
    return (recon - target).abs().mean() + sam_weight * spectral_angle_torch(recon, target).mean()


def sample_pixels(images, n_pixels: int, seed: int) -> np.ndarray:
    """Sample up to ``n_pixels`` finite spectra ``[n, B]`` (float32) from an iterable of [H,W,B] cubes.

    ``images`` is a list of callables or arrays; pixels are spread evenly over images. A callable may
    also return a frame read by row blocks (:class:`brfgs.data.pixels.FramePixels`: ``valid()`` its
    mask, ``take(flat)`` the chosen pixels): the same pixels are drawn without the cube in memory.
    """
    rng = np.random.default_rng(seed)
    n_img = len(images)
    per = max(1, int(math.ceil(n_pixels / max(n_img, 1))))
    out = []
    for item in images:
        cube = item() if callable(item) else item
        streamed = not isinstance(cube, np.ndarray)
        if streamed:
            ok = np.flatnonzero(cube.valid().ravel())
        else:
            flat = cube.reshape(-1, cube.shape[-1])
            ok = np.flatnonzero(np.isfinite(flat).all(-1))
        if ok.size == 0:
            continue
        pick = np.sort(rng.choice(ok, size=min(per, ok.size), replace=False))
        out.append(cube.take(pick) if streamed else np.asarray(flat[pick], np.float32))
    if not out:
        raise ValueError("no finite pixels to train the spectral autoencoder on")
    return np.concatenate(out, 0)


def train_autoencoder(
    pixels: np.ndarray,
    cfg: AutoencoderConfig,
    progress: bool = False,
) -> tuple[SpectralAutoencoder, list[float]]:
    """Train a :class:`SpectralAutoencoder` on spectra ``pixels [N, B]``; returns (model, loss history)."""
    gen = torch.Generator().manual_seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    x = torch.from_numpy(np.ascontiguousarray(pixels, np.float32))
    model = SpectralAutoencoder(x.shape[1], cfg.latent_dim, cfg.channels1, cfg.channels2)
    model.set_normalisation(x)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.steps, 1), eta_min=cfg.lr * 0.05)
    hist: list[float] = []
    it = range(cfg.steps)
    bar = None
    if progress:
        bar = tqdm(it, desc="autoencoder", leave=False)
        it = bar
    for step in it:
        idx = torch.randint(0, x.shape[0], (min(cfg.batch_size, x.shape[0]),), generator=gen)
        batch = x[idx]
        recon, _ = model(batch)
        loss = autoencoder_loss(recon, batch, cfg.sam_weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        hist.append(float(loss.item()))
        if bar is not None and step % 50 == 0:
            bar.set_postfix(loss=f"{hist[-1]:.4f}")
    model.eval()
    return model, hist


@torch.no_grad()
def evaluate_autoencoder(model: SpectralAutoencoder, pixels: np.ndarray, batch: int = 65536) -> dict:
    """Round-trip quality on spectra ``[N, B]``: mean/95th-percentile SAM (rad), RMSE, max abs error."""
    x = torch.from_numpy(np.ascontiguousarray(pixels, np.float32))
    sams, sq, mx = [], 0.0, 0.0
    for i in range(0, x.shape[0], batch):
        b = x[i : i + batch]
        r, _ = model(b)
        sams.append(spectral_angle_torch(r.double(), b.double()))
        sq += float(((r - b).double() ** 2).sum())
        mx = max(mx, float((r - b).abs().max()))
    s = torch.cat(sams)
    return {
        "n_pixels": int(x.shape[0]),
        "sam_mean_rad": float(s.mean()),
        "sam_p95_rad": float(torch.quantile(s.float(), 0.95)),
        "rmse": math.sqrt(sq / (x.shape[0] * x.shape[1])),
        "max_abs_error": mx,
    }


def autoencoder_state(model: SpectralAutoencoder, prefix: str = "decoder.") -> tuple[dict, dict]:
    """(tensors, metadata) for a safetensors file: weights under ``prefix`` and the architecture."""
    tensors = {prefix + k: v.detach().contiguous().clone() for k, v in model.state_dict().items()}
    return tensors, {"autoencoder": json.dumps(model.describe())}


def autoencoder_from_state(tensors: dict, meta: dict, prefix: str = "decoder.") -> SpectralAutoencoder:
    """Inverse of :func:`autoencoder_state`."""
    model = SpectralAutoencoder.from_description(json.loads(meta["autoencoder"]))
    sd = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
    model.load_state_dict(sd)
    model.eval()
    return model


def config_dict(cfg: AutoencoderConfig) -> dict:
    return asdict(cfg)
