"""Step 7: two-stage BRF-GS training (paper section 3.3).

    from brfgs.train import preset, train
    cfg = preset("fast")                         # TrainConfig; presets fast | paper | tiny
    model_path = train(scene_dir, out_dir, cfg)  # resumes an unfinished out_dir

Evaluation of a finished run is :func:`brfgs.analysis.evaluate.evaluate_run`; studies that train
and evaluate several runs (ablations, the demo) are in :mod:`brfgs.workflows`.
"""

from brfgs.train.config import TrainConfig, preset
from brfgs.train.trainer import Trainer, train

__all__ = ["TrainConfig", "Trainer", "preset", "train"]
