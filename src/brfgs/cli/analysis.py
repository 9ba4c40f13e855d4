"""``brfgs render | brf | products | export``: analysis of a trained model (brfgs.analysis).

All four read a trained model (a run folder with model.safetensors, or the model file
itself) without the training scene; ``brf`` reads the scene (for observations and, on
simulated scenes, truth) when it is available. One module per command (render.py, brf.py,
products.py, export.py); this one registers them in pipeline order.
"""

from __future__ import annotations

import typer

from brfgs.cli import brf, export, products, render


def register(app: typer.Typer) -> None:
    for module in (render, brf, products, export):
        module.register(app)
