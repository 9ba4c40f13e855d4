"""docs/study.toml, the manifest of the study in docs/results.md, is a valid `brfgs batch` manifest:
three methods on each of the five tuning scenes, the same seed and validation split for all, and the
SH-3 runs differ from the BRF-GS runs only in their variant (so they share stage 1)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from brfgs.cli import main
from brfgs.workflows.manifest import read_manifest

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("ts64", "sun20", "sun55", "forest64", "ts128")


def _copy(tmp_path: Path) -> Path:
    m = tmp_path / "study.toml"
    shutil.copy(ROOT / "docs" / "study.toml", m)
    for s in SCENES:
        (tmp_path / "scenes" / s).mkdir(parents=True)
        (tmp_path / "scenes" / s / "transforms.json").write_text('{"frames": []}\n')
    return m


def test_the_study_manifest_reads(tmp_path):
    scenes = {s.name: s for s in read_manifest(_copy(tmp_path)).scenes}
    assert sorted(scenes) == sorted(f"{s}-{m}" for s in SCENES for m in ("brf", "sh", "joint"))
    for s in SCENES:
        brf, sh, joint = (scenes[f"{s}-{m}"].config for m in ("brf", "sh", "joint"))
        assert brf["validation"] and brf["seed"] == 0 and brf["variant"] == "brf" and not brf["joint"]
        assert {k for k in brf if brf[k] != sh[k]} == {"variant"} and sh["variant"] == "sh"
        assert {k for k in brf if brf[k] != joint[k]} == {"joint"}
        assert scenes[f"{s}-brf"].products is None


def test_its_dry_run_lists_every_run(tmp_path, capsys):
    assert main(["batch", str(_copy(tmp_path)), "--dry-run"]) == 0
    assert len(re.findall(r"run train -> evaluate", capsys.readouterr().out)) == 15


def test_results_md_names_it():
    assert "docs/study.toml" in (ROOT / "docs" / "results.md").read_text() or \
        "study.toml" in (ROOT / "docs" / "results.md").read_text()
