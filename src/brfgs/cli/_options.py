"""Options shared by several commands (scene reading; the analysis of a trained model)."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.analysis.output import check_output_dir

__all__ = ["SceneArg", "RunArg", "read_scene", "check_output_dir"]

# The function bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).

SceneArg = typer.Argument(..., help="Scene folder (transforms.json + images/, docs/data-format.md).",
                          show_default=False)

RunArg = typer.Argument(..., help="Run folder of `brfgs train` (with model.safetensors) or a model file.",
                        show_default=False)


def read_scene(scene: Path, o, **kw):
    """:func:`brfgs.data.read_scene` with the scene-reading options ``o``
    (:class:`brfgs.data.options.SceneReadOptions`)."""
    from brfgs.data import read_scene as read

    o.validate()
    return read(scene, downscale=o.downscale, value_range=tuple(o.value_range),
                allow_outside_links=o.allow_outside_links, **kw)
