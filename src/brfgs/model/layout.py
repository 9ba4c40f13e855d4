"""Which tensors a model file (or checkpoint) of a given kind holds: one list for the writer and the reader.

The training set-up asks :func:`has_colors_kernels`, :func:`has_learned_normals` and
:func:`has_irradiance_scales` whether to make those tensors; :func:`model_tensor_names` lists, from a
file's metadata, every tensor a model of that kind holds, from the same code that makes and saves
them (the head's :func:`brfgs.brdf.head.head_param_shapes`, the decoder's and the neural head's
``state_dict``). :class:`brfgs.model.trained.TrainedModel` refuses to write a file that does not hold
exactly these, and :mod:`brfgs.model.schema` refuses to read one.

A kind of model: its appearance (brf, sh, neural, cir), head, spectral basis, the training options that
add tensors (``stage1_kernels``, ``learn_normals``, ``learn_irradiance``) and its phase (a checkpoint of
stage 1 holds no head yet). An option that the file's options do not record (a file written before the
option existed, config format 1) allows its tensors without requiring them.
"""

from __future__ import annotations

import torch

from brfgs.brdf.head import HeadConfig, head_param_shapes
from brfgs.model.features import NeuralHead
from brfgs.model.gaussians import GEOMETRY_KEYS
from brfgs.spectral.decoders import DESCRIPTION_KEYS, decoder_from_description

# name prefixes of the resume state a checkpoint adds to its model (brfgs.train.state)
RESUME_PREFIXES = ("optim.", "densify.", "rng.")
# the stage-1 colours and background: every model holds them (stage 1, or the CIR variant's one phase)
ALWAYS = tuple(f"param.{k}" for k in (*GEOMETRY_KEYS, "colors")) + ("extra.bg_colors",)


def has_colors_kernels(stage1_kernels: bool, variant: str, joint: bool) -> bool:
    """Whether the Gaussians carry ``colors_kernels`` (option ``stage1_kernels``, runs with a stage 1)."""
    return bool(stage1_kernels) and variant != "cir" and not joint


def has_learned_normals(variant: str, learn_normals: bool, head: HeadConfig | None) -> bool:
    """Whether the Gaussians carry learned shading ``normals`` (option ``learn_normals``, a head that uses normals)."""
    return variant == "brf" and bool(learn_normals) and head is not None and head.needs_normals


def has_irradiance_scales(variant: str, learn_irradiance: bool) -> bool:
    """Whether the model carries ``extra.log_irradiance`` (option ``learn_irradiance``, spectral variants)."""
    return variant != "cir" and bool(learn_irradiance)


class DescriptionError(ValueError):
    """The metadata's head or decoder description is not one brfgs makes (``field``: its key)."""

    def __init__(self, field: str, exc: Exception):
        super().__init__(f"{type(exc).__name__}: {exc}")
        self.field = field


def _by_option(names: list[str], value, on: bool, required: set, optional: set) -> None:
    """Add ``names`` to ``required`` when the option ``value`` is recorded and turns them on (``on``),
    to ``optional`` when the option is not recorded (None)."""
    if value is None:
        optional.update(names)
    elif on:
        required.update(names)


def _head_names(meta: dict) -> list[str]:
    """The appearance tensors of the file's head, from the code that makes them."""
    head, d = meta["head"], int(meta["latent_dim"])
    try:
        if head.get("kind") == "neural":
            with torch.random.fork_rng(devices=[]):  # only the names: leave the caller's random stream alone
                net = NeuralHead(d, int(head.get("hidden", 64)))
            return ["param.feat", *(f"neural.{k}" for k in net.state_dict())]
        return [f"param.{k}" for k in head_param_shapes(_head_config(head), 0, d)]
    except (KeyError, ValueError, TypeError, AttributeError) as exc:
        raise DescriptionError("head", exc) from None


def _head_config(head: dict) -> HeadConfig:
    try:
        return HeadConfig.from_dict(head)
    except (KeyError, ValueError, TypeError, AttributeError) as exc:
        raise DescriptionError("head", exc) from None


def decoder_names(meta: dict) -> list[str]:
    """The spectral decoder's tensors (``decoder.``) described by the file's metadata."""
    try:
        with torch.random.fork_rng(devices=[]):
            dec = decoder_from_description(meta)
    except (KeyError, ValueError, TypeError, AttributeError, RuntimeError) as exc:
        raise DescriptionError(DESCRIPTION_KEYS.get(meta.get("spectral_basis", "autoencoder"), "spectral_basis"),
                               exc) from None
    return [f"decoder.{k}" for k in dec.state_dict()]


def model_tensor_names(meta: dict) -> tuple[set[str], set[str]]:
    """(required, optional) tensor names of a model file with metadata ``meta`` (validated by
    :func:`brfgs.model.schema.check_metadata`): every other name under ``param.``, ``extra.``,
    ``decoder.`` or ``neural.`` is not one a model of this kind holds."""
    cfg = meta.get("config") or {}
    variant = cfg.get("variant", meta["appearance"])
    with_head = meta.get("phase") != "stage1"
    head = None if meta["head"].get("kind") == "neural" else _head_config(meta["head"])
    required, optional = set(ALWAYS), set()
    if meta["appearance"] != "cir":
        required.update(decoder_names(meta))
    if with_head:
        required.update(_head_names(meta))
        if meta["appearance"] != "cir":
            required.add("extra.bg_latent")
        _by_option(["param.normals"], cfg.get("learn_normals"),
                   has_learned_normals(variant, cfg.get("learn_normals"), head), required, optional)
        _by_option(["extra.log_irradiance"], cfg.get("learn_irradiance"),
                   has_irradiance_scales(variant, cfg.get("learn_irradiance")), required, optional)
    kernels = has_colors_kernels(cfg.get("stage1_kernels"), variant, bool(cfg.get("joint", False)))
    _by_option(["param.colors_kernels"], cfg.get("stage1_kernels"), kernels, required, optional)
    return required, optional - required


def layout_problem(names, meta: dict) -> tuple[str, str] | None:
    """(tensor name, what is wrong) for the first tensor a model of ``meta``'s kind lacks or does not
    hold among ``names``; None when ``names`` are exactly its tensors (plus a checkpoint's resume state)."""
    required, optional = model_tensor_names(meta)
    have = set(names)
    for name in sorted(required - have):
        return name, "missing tensor (every model of this kind holds it: a damaged file?)"
    for name in sorted(have - required - optional):
        if not name.startswith(RESUME_PREFIXES):
            return name, ("a tensor that this kind of model does not hold (a damaged file, or written by "
                          "another brfgs?)")
    return None



def check_written(tensors, meta: dict, path) -> None:
    """RuntimeError (a bug in brfgs, not in the input) when a file about to be written to ``path``
    would not hold exactly the tensors a model of its kind holds: the reader would refuse it."""
    problem = layout_problem(tensors, meta)
    if problem is not None:
        raise RuntimeError(f"brfgs would write an incomplete model file {path}: {problem[0]}: {problem[1]}")
