"""Differentiable 3D Gaussian rasterizer with three backends.

    from brfgs.render import rasterize
    out = rasterize(means, quats, scales, opacities, features, viewmat, K, W, H, backend="auto")
    out.image [H,W,C], out.alpha [H,W], out.depth [H,W], out.normal [H,W,3]|None, out.meta

Backends
--------
``torch``  readable reference in plain PyTorch (autograd), vectorised per 16×16 tile with a
           dense [pixels, K] alpha block and cumprod compositing. Used by the tests.
``cpu``    the fast path: numba-compiled, multi-threaded projection (+ hand-written backward),
           stable depth sort, tile binning, tile rasterization iterating each Gaussian only over
           the row spans of its α ≥ 1/255 ellipse, and a race-free hand-written backward (one
           gradient row per tile–Gaussian entry, reduced per Gaussian afterwards).
``cuda``   gsplat's CUDA ``rasterization`` (needs a GPU and ``pip install brfgs[cuda]``). CPU inputs
           (a model kept on the CPU, as ``brfgs train/render --backend cuda``) are moved to the GPU
           and the outputs, meta and gradients back: only the rasterization runs there.
``auto``   ``cuda`` when the inputs are CUDA tensors, else ``cpu``.

Semantics (all backends; details in ``brfgs.render._common``): EWA projection with the 0.3 px²
low-pass, near/far planes at 0.01 m / 1e10 m, 16×16 tiles, front-to-back alpha compositing in
stable depth order, α clamped to 0.99, pairs with α < 1/255 skipped, a pixel stops before its
transmittance drops below 1e-4.
``depth`` is the expected depth Σ wᵢ zᵢ / Σ wᵢ (normalised by alpha; 0 where alpha = 0);
the unnormalised Σ wᵢ zᵢ is ``meta["depth_accum"]``. ``normal`` composites the given per-Gaussian
normals like features (Σ wᵢ nᵢ, not normalised). ``meta["means2d"].grad`` after backward is the
screen-space positional gradient in pixels (3DGS densification statistic); with ``absgrad=True``
``meta["means2d"].absgrad`` is AbsGS's: each pixel's gradient summed in absolute value. ``image``
is premultiplied by alpha; a background is the caller's (``image + (1 − alpha)·bg``).

Geometry shared with the reflectance head, the trainer and the evaluation (one copy of each
formula) is in ``brfgs.render.geometry``: ``quat_to_rotmat``, ``project_pinhole`` and
``normals_from_depth``.

Threads
-------
:func:`configure_threads(n)` sets numba's and PyTorch's pools to the same ``n`` (default
``$BRFGS_NUM_THREADS`` or all cores); the two pools never run at the same time inside
``rasterize`` (numba kernels and torch glue alternate), so they do not compete. Without a call,
the first ``cpu`` render gives numba torch's thread count (or ``$BRFGS_NUM_THREADS`` to both) and
leaves torch's setting alone. Use ``configure_threads(1)`` in each of several worker processes.
Idle OpenMP threads spin 300 000 times before they sleep unless told otherwise: the ``brfgs`` command
sets ``GOMP_SPINCOUNT=1000`` before torch is imported (a library user can do the same), which was as fast
as spinning on a quiet machine and as fast as ``OMP_WAIT_POLICY=PASSIVE`` on an oversubscribed one
(BENCHMARKS.md, "OpenMP threads").

numba kernels are compiled with ``cache=True``: the first use in a fresh checkout compiles for
tens of seconds and stores the result in ``__pycache__``; later processes load it.
"""

from brfgs.render.rasterize import BACKENDS, RenderOutput, configure_threads, rasterize, resolve_backend

__all__ = ["BACKENDS", "RenderOutput", "configure_threads", "rasterize", "resolve_backend"]
