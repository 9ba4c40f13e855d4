"""Step 7: two-stage BRF-GS training (paper section 3.3).

    from brfgs.train import preset, train
    cfg = preset("fast")                         # TrainConfig; presets fast | paper | tiny
    model_path = train(scene_dir, out_dir, cfg)  # resumes an unfinished out_dir

Evaluation of a finished run is :func:`brfgs.evaluation.evaluate.evaluate_run`; studies that train
and evaluate several runs (ablations, the demo) are in :mod:`brfgs.workflows`.
"""

import importlib

# Exported names load on first use (PEP 562): brfgs.train.config stays importable without torch.
_WHERE = {"TrainConfig": "brfgs.train.config", "preset": "brfgs.train.presets", "Trainer": "brfgs.train.trainer",
          "train": "brfgs.train.trainer"}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'brfgs.train' has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
