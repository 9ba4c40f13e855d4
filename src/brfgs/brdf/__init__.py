"""Directional reflectance of BRF-GS: kernels, hybrid Gaussian head, SH baseline, integrals.

Modules:
    kernels    Ross-Thick, Li-Sparse-R, Cook–Torrance (paper eqs 14–23), batched torch.
    geometry   Gaussian normals (smallest-scale axis facing ω_o), view and sun directions
               (quat_to_rotmat re-exported from brfgs.render.geometry).
    head       hybrid_latent (eq. 12), HeadConfig / init_head_params / evaluate_head.
    sh         real spherical harmonics (3DGS baseline) in latent space.
    fused      numba-fused CPU kernels + combination with hand-written gradients (the
               default of hybrid_latent on CPU tensors; backend="torch" for CUDA).
    integrals  black-sky / white-sky kernel integrals for albedo products (cached).
    reference  naive angle-based head (benchmark baseline and test cross-check).
    bench      micro-benchmark of the head (python -m brfgs.brdf.bench).
    plots      kernel grids, CSV and the reference figure of ``brfgs kernels``.
"""
