"""3DGS-style adaptive density control (Kerbl et al. 2023; gsplat's DefaultStrategy as the idea).

Every ``refine_every`` steps between ``refine_start`` and ``refine_stop``:
- Gaussians whose mean screen-space positional gradient (NDC units) exceeds ``grow_grad2d``
  are cloned when small (max scale <= ``grow_scale3d`` * extent) or split in two when large
  (children sampled from the parent, scales / 1.6);
- Gaussians with opacity < ``prune_opacity`` or (after the first opacity reset) larger than
  ``prune_scale3d`` * extent are removed.
Every ``reset_every`` steps opacities are clamped to 2 * ``prune_opacity``.
The optimiser moments follow the row edits (new rows start at zero).
"""

from __future__ import annotations

import torch

from brfgs.model.densify_config import ADCConfig
from brfgs.model.gaussians import GaussianModel, inverse_sigmoid
from brfgs.model.optim import NamedAdam
from brfgs.render.geometry import quat_to_rotmat


class DensifyState:
    """Running gradient statistics between refinements (checkpointed)."""

    def __init__(self, n: int):
        self.grad2d = torch.zeros(n)
        self.count = torch.zeros(n)
        self.n_resets = 0

    def tensors(self, prefix: str = "densify.") -> dict[str, torch.Tensor]:
        return {prefix + "grad2d": self.grad2d.clone(), prefix + "count": self.count.clone()}

    def load(self, tensors: dict[str, torch.Tensor], n_resets: int, prefix: str = "densify.") -> None:
        self.grad2d = tensors[prefix + "grad2d"].clone()
        self.count = tensors[prefix + "count"].clone()
        self.n_resets = int(n_resets)


@torch.no_grad()
def accumulate(
    state: DensifyState,
    means2d: torch.Tensor,  # [N, 2] px, its .grad set by the backward pass
    visible: torch.Tensor,  # [N] bool
    width: int,
    height: int,
    grad_scale: float = 1.0,
    absgrad: bool = False,
) -> None:
    """Add this step's screen-space gradient norms (pixels -> NDC) of visible Gaussians; the
    gradient is multiplied by ``grad_scale`` first (the number of views a mean loss averaged).
    With ``absgrad`` the gradient is AbsGS's ``means2d.absgrad`` (per-pixel gradients summed in
    absolute value, set by :func:`brfgs.render.rasterize` with ``absgrad=True``)."""
    src = getattr(means2d, "absgrad", None) if absgrad else means2d.grad
    if src is None:
        return
    g = src.detach().clone()  # [N, 2] d loss / d pixel position
    if grad_scale != 1.0:
        g *= grad_scale
    g[:, 0] *= width / 2.0
    g[:, 1] *= height / 2.0
    norm = g.norm(dim=-1)
    vis = visible.bool() & torch.isfinite(norm)
    state.grad2d[vis] += norm[vis]
    state.count[vis] += 1


@torch.no_grad()
def refine(
    model: GaussianModel,
    opt: NamedAdam,
    state: DensifyState,
    cfg: ADCConfig,
    extent: float,
    gen: torch.Generator,
    max_gaussians: int,
) -> dict:
    """Clone, split and prune once, growing to at most ``max_gaussians``; returns counts. Resets the
    statistics."""
    n = model.n
    avg = state.grad2d / state.count.clamp_min(1)
    high = avg > cfg.grow_grad2d
    scales = torch.exp(model.params["log_scales"])  # [N, 3] m, without the 3D filter (as Mip-Splatting)
    small = scales.max(-1).values <= cfg.grow_scale3d * extent
    room = max(max_gaussians - n, 0)
    clone = high & small
    split = high & ~small
    # respect the cap: keep the highest-gradient candidates
    n_new = int(clone.sum()) + int(split.sum())
    if n_new > room:
        cand = torch.nonzero(clone | split).squeeze(1)
        keep = cand[torch.argsort(avg[cand], descending=True)[:room]]
        sel = torch.zeros(n, dtype=torch.bool)
        sel[keep] = True
        clone &= sel
        split &= sel
    n_clone, n_split = int(clone.sum()), int(split.sum())

    p = model.params
    # split: two children sampled inside the parent, parent removed
    if n_split:
        rot = quat_to_rotmat(p["quats"][split])  # [S,3,3]
        sc = scales[split]  # [S,3]
        noise = torch.randn(2, n_split, 3, generator=gen) * sc[None]
        child_means = (p["means"][split][None] + torch.einsum("sij,ksj->ksi", rot, noise)).reshape(-1, 3)
    new = {}
    for k, v in p.items():
        v = v.detach()
        parts = [v]
        if n_clone:
            parts.append(v[clone])
        if n_split:
            if k == "means":
                parts.append(child_means)
            elif k == "log_scales":
                parts.append((v[split] - torch.log(torch.tensor(1.6))).repeat(2, *[1] * (v.dim() - 1)))
            else:
                parts.append(v[split].repeat(2, *[1] * (v.dim() - 1)))
        new[k] = torch.cat(parts, 0)
    keep_rows = torch.cat([~split, torch.ones(n_clone + 2 * n_split, dtype=torch.bool)])
    # prune
    opa = torch.sigmoid(new["opacity_logits"])
    prune = opa < cfg.prune_opacity
    if state.n_resets > 0:
        prune |= torch.exp(new["log_scales"]).max(-1).values > cfg.prune_scale3d * extent
    keep_rows &= ~prune
    if keep_rows.sum() == 0:  # never remove everything
        keep_rows[torch.argmax(opa)] = True
    new = {k: v[keep_rows] for k, v in new.items()}
    model.replace(new)

    def fix(name, mom):
        if mom.shape[0] != n:
            return mom  # not per-Gaussian (e.g. decoder)
        parts = [mom]
        if n_clone:
            parts.append(torch.zeros_like(mom[clone]))
        if n_split:
            z = torch.zeros_like(mom[split])
            parts += [z, z]
        return torch.cat(parts, 0)[keep_rows]

    opt.edit_rows(lambda k, m: fix(k, m) if k in p else m)
    state.grad2d = torch.zeros(model.n)
    state.count = torch.zeros(model.n)
    return {"cloned": n_clone, "split": n_split, "pruned": int((~keep_rows).sum()) - n_split, "n": model.n}


@torch.no_grad()
def reset_opacity(model: GaussianModel, opt: NamedAdam, state: DensifyState, cfg: ADCConfig) -> None:
    """Clamp opacities to 2 * prune_opacity (3DGS opacity reset); zero their moments."""
    lo = float(inverse_sigmoid(cfg.prune_opacity * 2.0))
    p = model.params["opacity_logits"]
    p.data.clamp_(max=lo)
    if "opacity_logits" in opt.m:
        opt.m["opacity_logits"].zero_()
        opt.v["opacity_logits"].zero_()
    state.n_resets += 1
