"""Step 7: two-stage BRF-GS training, evaluation, ablations (paper section 3.3, 4.2-4.5).

    from brfgs.train import preset, train, evaluate_run
    cfg = preset("fast")                       # TrainConfig; presets fast | paper | tiny
    model_path = train(scene_dir, out_dir, cfg)  # resumes an unfinished out_dir
    metrics = evaluate_run(out_dir)            # OUT/metrics.json, ENVI renders, CIR PNGs
"""

from brfgs.train.config import TrainConfig, preset
from brfgs.train.evaluate import evaluate_run
from brfgs.train.trainer import LoadedModel, Trainer, train

__all__ = ["LoadedModel", "TrainConfig", "Trainer", "evaluate_run", "preset", "train"]
