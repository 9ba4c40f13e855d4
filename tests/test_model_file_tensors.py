"""A model file holds exactly the tensors brfgs saves with its kind of model (appearance, spectral
basis, options, phase): one missing, with or without the checksum, or one of another kind is refused
in one line naming the file and the tensor; the writer refuses to write such a file; files written
before an option existed need not hold its tensors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from brfgs.cli import main
from brfgs.errors import UserError
from brfgs.model import TrainedModel
from brfgs.model.io import FORMAT, content_digest, load
from brfgs.model.layout import model_tensor_names
from tiny_runs import STAGE1, run

FORMAT1 = Path(__file__).parent / "data" / "format1" / "finished"
# the autoencoder, the linear basis, the SH head, --shadows, the neural head, the CIR baseline, joint training
KINDS = ("brf", "brf_linear", "sh", "shadows", "neural", "cir", "joint")


def _write(path: Path, tensors: dict, meta: dict, checksum: bool) -> Path:
    """A model file of ``tensors`` and ``meta`` (metadata as written), with or without its checksum key."""
    text = json.dumps(meta)
    md = {"format": FORMAT, "brfgs": text}
    if checksum:
        md["sha256"] = content_digest(tensors, text)
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(path), metadata=md)
    return path


def _refused_in_one_line(path: Path, tensor: str, out: Path, capsys) -> None:
    with pytest.raises(UserError) as err:
        TrainedModel.load(path)
    assert err.value.file == str(path) and err.value.field == tensor, str(err.value)
    capsys.readouterr()
    code = main(["render", str(path), "--view-zenith", "20", "--view-azimuth", "45", "-o", str(out), "-q",
                 "--backend", "torch"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and str(path) in lines[0] and f"'{tensor}'" in lines[0], lines
    assert not out.exists()


@pytest.mark.parametrize("kind", KINDS)
def test_every_saved_tensor_is_required(kind, tmp_path, capsys):
    tensors, meta = load(run(kind) / "model.safetensors")
    required, optional = model_tensor_names(meta)
    assert set(tensors) == required and not optional  # today's files: every option recorded
    assert TrainedModel.load(run(kind)).n_gaussians > 0
    for k, name in enumerate(sorted(tensors)):
        rest = {n: t for n, t in tensors.items() if n != name}
        for checksum in (True, False):
            bad = _write(tmp_path / f"{k}_{checksum}.safetensors", rest, meta, checksum)
            _refused_in_one_line(bad, name, tmp_path / f"r{k}", capsys)


def test_a_model_without_its_checksum_and_its_stage_1_colours_does_not_render(tmp_path, capsys):
    tensors, meta = load(run("brf") / "model.safetensors")
    del tensors["param.colors"]
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    bad = _write(run_dir / "model.safetensors", tensors, meta, checksum=False)
    _refused_in_one_line(bad, "param.colors", tmp_path / "r", capsys)
    capsys.readouterr()
    assert main(["evaluate", str(run_dir), "--quiet", "--backend", "torch"]) == 2
    assert "param.colors" in capsys.readouterr().err


@pytest.mark.parametrize("name, shape", [("param.unknown", (None,)), ("extra.unknown", (3,)),
                                         ("decoder.unknown", (2,)), ("neural.net.0.weight", (4, 4)),
                                         ("something.else", (1,))])
def test_a_tensor_of_another_kind_is_refused(name, shape, tmp_path, capsys):
    tensors, meta = load(run("brf") / "model.safetensors")
    n = tensors["param.means"].shape[0]
    tensors[name] = torch.zeros(tuple(n if s is None else s for s in shape))
    for checksum in (True, False):
        bad = _write(tmp_path / f"m_{checksum}.safetensors", tensors, meta, checksum)
        _refused_in_one_line(bad, name, tmp_path / "r", capsys)


def test_a_linear_model_holding_the_autoencoder_s_tensors_is_refused(tmp_path, capsys):
    tensors, meta = load(run("brf_linear") / "model.safetensors")
    ae = load(run("brf") / "model.safetensors")[0]
    tensors.update({k: v for k, v in ae.items() if k.startswith("decoder.")})
    bad = _write(tmp_path / "mixed.safetensors", tensors, meta, checksum=True)
    _refused_in_one_line(bad, "decoder.band_mean", tmp_path / "r", capsys)


def test_checkpoints_load_with_their_resume_state():
    """A checkpoint is a model plus optim./densify./rng. tensors; at the end of stage 1 it has no head."""
    for path in (run("brf") / STAGE1, run("sh") / "checkpoints" / "last.safetensors"):
        tensors, meta = load(path)
        assert any(k.startswith("optim.") for k in tensors)
        assert TrainedModel.load(path).n_gaussians == tensors["param.means"].shape[0]
    tensors, meta = load(run("brf") / STAGE1)
    assert not {"param.z_iso", "extra.bg_latent"} & set(tensors)
    del tensors["param.colors_kernels"]
    with pytest.raises(UserError) as err:
        TrainedModel.from_file_contents(tensors, meta, Path("stage1.safetensors"))
    assert err.value.field == "param.colors_kernels"


def test_the_writer_refuses_a_model_its_reader_would_refuse(tmp_path):
    tm = TrainedModel.load(run("brf"))
    del tm.extra["bg_latent"]
    with pytest.raises(RuntimeError, match="extra.bg_latent"):
        tm.save(tmp_path / "model.safetensors")
    assert not (tmp_path / "model.safetensors").exists()


def test_files_from_before_an_option_need_not_hold_its_tensors(tmp_path):
    """0.1.0's model (config format 1) loads; without the options stage1_kernels and learn_normals recorded
    (a file from before them) it needs neither tensor; with them recorded it needs both."""
    tm = TrainedModel.load(FORMAT1)
    assert "colors_kernels" in tm.gaussians and "normals" in tm.gaussians
    tensors, meta = load(FORMAT1 / "model.safetensors")
    for name, option in (("param.colors_kernels", "stage1_kernels"), ("param.normals", "learn_normals")):
        rest = {k: v for k, v in tensors.items() if k != name}  # exact across CPUs: tensor names
        with pytest.raises(UserError) as err:
            TrainedModel.from_file_contents(rest, meta, Path("m.safetensors"))
        assert err.value.field == name  # exact across CPUs: a tensor name
        older = json.loads(json.dumps(meta))
        del older["config"][option]
        assert TrainedModel.from_file_contents(rest, older, Path("m.safetensors")).n_gaussians > 0
        assert TrainedModel.from_file_contents(tensors, older, Path("m.safetensors")).n_gaussians > 0
    assert tm.save(tmp_path / "again.safetensors").is_file()  # the writer agrees
