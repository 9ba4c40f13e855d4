"""``brfgs bench train``: a training run timed with the fused spectral decoder and with the reference
decoder, alternating in one process, and both scored against the scene's truth.

Each round trains the same configuration twice into ``OUT/fused_<r>`` and ``OUT/reference_<r>`` (same
seed; the reference rounds decode with :meth:`SpectralAutoencoder.decode` through
:func:`brfgs.spectral.fast_decode.reference_decoding`), reads each run's phase timings from run.json
and evaluates the test views. Reported: the median seconds per phase and per step of each decoder,
their ratio (reference / fused, same run), and the CIR PSNR and SAM of both (the fused decoder must not
change accuracy beyond float rounding: the benchmark reports the difference).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numba
import numpy as np
import torch

from brfgs.evaluation.evaluate import evaluate_run
from brfgs.spectral.autoencoder import AutoencoderConfig, train_autoencoder
from brfgs.spectral.fast_decode import fast_decode, reference_decoding
from brfgs.train import TrainConfig, train

__all__ = ["bench_train"]

PHASES = ("bands", "init", "autoencoder", "stage1", "stage2")


def _one_run(scene: Path, out: Path, cfg: TrainConfig, reference: bool) -> dict:
    """Train (overwriting ``out``), evaluate against truth; timings and metrics of the run."""
    t0 = time.perf_counter()
    with reference_decoding() if reference else contextlib.nullcontext():
        train(scene, out, cfg, overwrite=True, progress=False, log=lambda *a, **k: None)
        wall = time.perf_counter() - t0
        res = evaluate_run(out, scene, write_images=False, progress=False)
    run = json.loads((out / "run.json").read_text())
    timings, used = run["timings_s"], run["config"]  # the steps used (scaled to the training views)
    against = res["against"].get("truth") or res["against"]["observed"]
    return {"wall_s": wall, "timings_s": {k: timings.get(k) for k in PHASES},
            "steps": {"stage1": used["stage1_steps"], "stage2": used["stage2_steps"]},
            "psnr": against["mean"]["psnr"], "sam": against["mean"]["sam"],
            "against": "truth" if "truth" in res["against"] else "observed"}


def _warm_up() -> None:
    """Load the numba kernels and PyTorch's first-use state before anything is timed."""
    rng = np.random.default_rng(0)
    ae, _ = train_autoencoder(rng.random((512, 24), dtype=np.float32), AutoencoderConfig(latent_dim=4, steps=5,
                                                                                         batch_size=64))
    ae.requires_grad_(False)
    z = torch.zeros(64, 4, requires_grad=True)
    fast_decode(ae, z).sum().backward()


def bench_train(scene: str | Path, out: str | Path, cfg: TrainConfig, repeats: int = 1) -> dict:
    """Time ``cfg`` on ``scene`` with both decoders, ``repeats`` alternating rounds (module docstring)."""
    scene, out = Path(scene), Path(out)
    _warm_up()
    load_before = os.getloadavg()
    runs: dict[str, list[dict]] = {"fused": [], "reference": []}
    for r in range(repeats):
        for name in runs:
            runs[name].append(_one_run(scene, out / f"{name}_{r}", cfg, reference=name == "reference"))
    summary = {}
    for name, rs in runs.items():
        steps = rs[0]["steps"]
        med = {k: statistics.median(x["timings_s"][k] for x in rs) for k in PHASES if rs[0]["timings_s"][k] is not None}
        summary[name] = {"median_phase_s": med, "median_wall_s": statistics.median(x["wall_s"] for x in rs),
                         "ms_per_step": {k: 1000 * med[k] / steps[k] for k in steps if k in med and steps[k]},
                         "psnr": [x["psnr"] for x in rs], "sam": [x["sam"] for x in rs]}
    f, ref = summary["fused"], summary["reference"]
    ratios = {k: ref["median_phase_s"][k] / f["median_phase_s"][k] for k in f["median_phase_s"]
              if f["median_phase_s"][k] > 0}
    return {"machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "torch": torch.__version__, "numba": numba.__version__,
                        "torch_threads": torch.get_num_threads(), "load_average_1_5_15_before": list(load_before),
                        "load_average_1_5_15_after": list(os.getloadavg())},
            "scene": str(scene), "repeats": repeats, "config": cfg.to_dict(), "runs": runs, "summary": summary,
            "speedup_vs_reference": {**ratios, "wall": ref["median_wall_s"] / f["median_wall_s"]},
            "psnr_difference_db": statistics.median(f["psnr"]) - statistics.median(ref["psnr"]),
            "sam_ratio": statistics.median(f["sam"]) / statistics.median(ref["sam"])}
