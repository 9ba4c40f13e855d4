"""A small Adam over named tensors whose rows can be cloned, split and pruned.

3DGS densification changes the number of Gaussians, so the optimiser state must follow
row edits; keeping the state as plain named tensors also makes checkpoints (safetensors,
tensors only) and exact resume simple. Update rule = torch.optim.Adam.
"""

from __future__ import annotations

import torch


class NamedAdam:
    """Adam on a dict ``{name: tensor}`` with per-name learning rates (``lrs``)."""

    def __init__(self, lrs: dict[str, float], betas=(0.9, 0.999), eps: float = 1e-15):
        self.lrs = dict(lrs)
        self.b1, self.b2 = betas
        self.eps = eps
        self.m: dict[str, torch.Tensor] = {}
        self.v: dict[str, torch.Tensor] = {}
        self.t: dict[str, int] = {}

    @torch.no_grad()
    def step(self, params: dict[str, torch.Tensor]) -> None:
        """One Adam step for every named tensor that has an lr > 0 and a gradient."""
        for name, p in params.items():
            lr = self.lrs.get(name, 0.0)
            if lr <= 0 or p.grad is None:
                continue
            g = p.grad
            if name not in self.m or self.m[name].shape != p.shape:
                self.m[name] = torch.zeros_like(p)
                self.v[name] = torch.zeros_like(p)
                self.t.setdefault(name, 0)
            t = self.t[name] + 1
            self.t[name] = t
            m, v = self.m[name], self.v[name]
            m.mul_(self.b1).add_(g, alpha=1 - self.b1)
            v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
            bc1 = 1 - self.b1**t
            bc2 = 1 - self.b2**t
            denom = (v / bc2).sqrt_().add_(self.eps)
            p.addcdiv_(m, denom, value=-lr / bc1)

    @staticmethod
    def zero_grad(params: dict[str, torch.Tensor]) -> None:
        for p in params.values():
            p.grad = None

    # -- row edits ---------------------------------------------------------------
    def edit_rows(self, fn) -> None:
        """Apply ``fn(name, tensor) -> tensor`` to the moments of every per-Gaussian state."""
        for d in (self.m, self.v):
            for k in list(d):
                out = fn(k, d[k])
                if out is None:
                    del d[k]
                else:
                    d[k] = out

    # -- checkpoint ------------------------------------------------------------------
    def state_tensors(self, prefix: str = "optim.") -> dict[str, torch.Tensor]:
        out = {}
        for k in self.m:
            out[f"{prefix}m.{k}"] = self.m[k].contiguous().clone()
            out[f"{prefix}v.{k}"] = self.v[k].contiguous().clone()
        return out

    def state_meta(self) -> dict:
        return {"t": dict(self.t), "lrs": dict(self.lrs)}

    def load(self, tensors: dict[str, torch.Tensor], meta: dict, prefix: str = "optim.") -> None:
        self.t = {k: int(v) for k, v in meta["t"].items()}
        self.m, self.v = {}, {}
        for k, v in tensors.items():
            if k.startswith(prefix + "m."):
                self.m[k[len(prefix) + 2 :]] = v.clone()
            elif k.startswith(prefix + "v."):
                self.v[k[len(prefix) + 2 :]] = v.clone()
