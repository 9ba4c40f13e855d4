"""The manifest of ``brfgs batch``: the scenes of a batch with their options (TOML, JSON or YAML).

Schema (TOML shown; a JSON or YAML file holds the same keys, ``scenes`` may stand for ``scene``,
and a JSON/YAML file that is just a list is the list of scenes). Paths are relative to the
manifest's folder::

    out = "runs"                 # output root (optional; default <manifest folder>/<manifest stem>_batch;
                                 # `brfgs batch --out` overrides it)
    [defaults]                   # options of every scene (optional); a scene's own keys override them
    preset = "fast"              # the TrainConfig preset the other training options start from (default fast)
    poses = "known"              # any TrainConfig field: the options of `brfgs train`, with '_' for '-'
    num_cpus = 2                 # Ray resources of each scene's task (default 1 CPU, 0 GPUs; GPUs may be
    num_gpus = 0                 #   fractions); the task's torch/numba threads = num_cpus unless `threads` is given
    products = true              # brfgs products after evaluation (default: true for variant brf), or a
                                 #   table of its options: size, half_extent_m, sun_zenith_deg,
                                 #   nbar_sun_zenith_deg, albedo_sun_zenith_deg, min_alpha, check_decoder, mcd43
    [[scene]]
    scene = "flights/valley"     # the scene folder (required)
    name = "valley"              # optional: default the scene folder's name; letters, digits, '.', '_', '-'
    out = "elsewhere/valley"     # optional: the scene's output folder, default OUT/<name>
    seed = 1
    [scene.densify]              # nested options as in config.json
    max_gaussians = 200000

A misspelt key, a value of the wrong type or out of range is a :class:`UserError` naming the
manifest and the field (``scene[2].stage1_step``: the second scene): each scene's training options
pass TrainConfig.validate(), its backend is named, its whole numbers are bounded (step counts by
MAX_STEPS), products options pass ProductsOptions.validate() and resources are bounded. The paths
(:mod:`brfgs.workflows.manifest_paths`): output folders are folders, never lie inside (or contain)
a scene folder, and no two scenes share one. :func:`check_manifest` collects every scene's problem
(``--dry-run`` lists them); :func:`read_manifest` raises the first.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import os
import re
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path

from brfgs.errors import UserError
from brfgs.products.options import ProductsOptions
from brfgs.train.config import TrainConfig
from brfgs.train.presets import PRESETS, preset
from brfgs.workflows.manifest_paths import Resolver, check_paths

try:  # YAML manifests only when PyYAML is installed (Ray brings it); TOML and JSON always work
    import yaml
except ImportError:  # pragma: no cover - depends on the environment
    yaml = None

TOP_KEYS = ("out", "defaults", "scene", "scenes")
SCENE_KEYS = ("name", "scene", "out")                   # per scene only
BATCH_KEYS = ("products", "num_cpus", "num_gpus")       # per scene or in [defaults]
TRAIN_KEYS = tuple(f.name for f in dataclasses.fields(TrainConfig))
PRODUCT_KEYS = tuple(f.name for f in dataclasses.fields(ProductsOptions) if f.name not in ("backend", "overwrite",
                                                                                            "progress"))
RUN_DIR = "run"          # the training run folder inside a scene's output folder
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")


@dataclass(frozen=True)
class BatchScene:
    """One scene of a batch, validated: absolute paths, the full training options and the task's resources."""

    name: str
    scene: Path                 # the scene folder (transforms.json + images/)
    out: Path                   # the scene's output folder: run/, batch.json, batch.log, error.log
    config: dict                # TrainConfig.to_dict() (its seed makes the model reproducible)
    products: dict | None       # ProductsOptions fields of `brfgs products`; None: no products
    num_cpus: int               # Ray CPUs of the task = its torch/numba threads unless config["threads"] > 0
    num_gpus: float             # Ray GPUs of the task
    index: int = 0              # the scene's place in the manifest (1-based: scene[index])

    @property
    def run(self) -> Path:
        """The training run folder (model.safetensors, metrics.json, analysis/products/)."""
        return self.out / RUN_DIR


@dataclass(frozen=True)
class Manifest:
    """A read manifest: its file, the output root (summary.md/.csv/.json) and the scenes in order."""

    path: Path
    out: Path
    scenes: list[BatchScene]


def _absolute(base: Path, value: str | Path) -> Path:
    """``value`` (a path in the manifest, or given on the command line) made absolute against ``base``
    (``..`` collapsed, links not followed)."""
    return Path(os.path.normpath(Path(base).absolute() / Path(value).expanduser()))


def load_manifest_data(path: Path):
    """The manifest's parsed content (a dict, or a list of scenes); UserError naming the file otherwise."""
    if not path.is_file():
        raise UserError("manifest not found", file=path)
    suffix = path.suffix.lower()
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise UserError("not a text file", file=path) from None
    if suffix == ".toml":
        try:
            return tomllib.loads(text)
        except (tomllib.TOMLDecodeError, RecursionError) as exc:
            raise UserError(f"not a valid TOML file ({exc})", file=path) from None
    if suffix == ".json":
        try:
            return json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise UserError(f"not a valid JSON file ({exc})", file=path) from None
    if suffix in (".yaml", ".yml"):
        if yaml is None:
            raise UserError("reading a YAML manifest needs PyYAML (pip install pyyaml; brfgs[scale] brings it); "
                            "or write the manifest as TOML or JSON", file=path)
        try:
            return yaml.safe_load(text)
        except (yaml.YAMLError, RecursionError) as exc:
            raise UserError(f"not a valid YAML file ({(str(exc) or type(exc).__name__).splitlines()[0]})",
                            file=path) from None
    raise UserError("a manifest is a .toml, .json, .yaml or .yml file", file=path)


def _unknown(key: str, allowed, file: Path, field: str) -> UserError:
    key = str(key)  # YAML keys may be numbers
    close = difflib.get_close_matches(key, list(allowed), n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return UserError(f"unknown option '{key}'{hint}", file=file, field=field)


def _sections(data, file: Path) -> tuple[str | None, dict, list]:
    """(out, defaults, raw scenes) of the manifest's content."""
    if isinstance(data, list):
        data = {"scene": data}
    if not isinstance(data, dict):
        raise UserError("expected a table of 'out', 'defaults' and the list 'scene' (or a list of scenes)", file=file)
    for key in data:
        if key not in TOP_KEYS:
            raise _unknown(key, TOP_KEYS, file, key)
    if "scene" in data and "scenes" in data:
        raise UserError("give the scenes as 'scene' or as 'scenes', not both", file=file, field="scenes")
    scenes = data.get("scene", data.get("scenes"))
    if not isinstance(scenes, list) or not scenes or not all(isinstance(s, dict) for s in scenes):
        raise UserError("expected a non-empty list of scenes ([[scene]] tables in TOML)", file=file, field="scene")
    defaults = data.get("defaults") or {}
    if not isinstance(defaults, dict):
        raise UserError("expected a table of options", file=file, field="defaults")
    out = data.get("out")
    if out is not None and not (isinstance(out, str) and out):
        raise UserError(f"expected a folder path, got {out!r}", file=file, field="out")
    return out, defaults, scenes


def _check_keys(raw: dict, where: str, file: Path, per_scene: bool) -> None:
    allowed = (SCENE_KEYS if per_scene else ()) + BATCH_KEYS + TRAIN_KEYS
    for key in raw:
        if key in SCENE_KEYS and not per_scene:
            raise UserError(f"'{key}' is set per scene, not in [defaults]", file=file, field=f"{where}.{key}")
        if key not in allowed:
            raise _unknown(key, allowed, file, f"{where}.{key}")


MAX_STEPS = 10_000_000        # a step count or interval (names ending in _steps, _every, _start, _stop)
MAX_INT = 2**31 - 1           # any other whole number (counts, sizes, seeds)
MAX_CPUS, MAX_GPUS = 1_000_000, 100_000
_STEP_SUFFIXES = ("_steps", "_every", "_start", "_stop")


def _shape(v):
    """What TrainConfig.from_dict's type check sees of a value: its type (finiteness for floats), the
    shapes of a list's items and of a table's entries."""
    if isinstance(v, dict):
        return dict, tuple((k, _shape(x)) for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return list, tuple(_shape(x) for x in v)
    if isinstance(v, float):
        return float, math.isfinite(v)
    return type(v)


@functools.cache
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _check_ints(given: dict, cls, file: Path, where: str) -> None:
    """UserError unless every whole-number option in ``given`` (fields of ``cls``, tables recursively)
    lies in 0..MAX_INT, and step counts and intervals in 0..MAX_STEPS."""
    hints = _hints(cls)
    for key, v in given.items():
        tp = hints.get(key)
        if isinstance(v, dict) and dataclasses.is_dataclass(tp):
            _check_ints(v, tp, file, f"{where}.{key}")
        elif tp is int and isinstance(v, int):
            top = MAX_STEPS if key.endswith(_STEP_SUFFIXES) else MAX_INT
            if not 0 <= v <= top:
                raise UserError(f"expected a whole number in 0..{top}, got {v}", file=file, field=f"{where}.{key}")


def _construct(d: dict) -> TrainConfig:
    """TrainConfig of options in config.json's form whose types TrainConfig.from_dict has accepted
    (tables made option objects, lists made tuples, as from_dict does)."""
    kw = dict(d)
    del kw["format_version"]
    tables, tuples = _table_and_tuple_fields()
    for key, tp in tables:
        kw[key] = tp(**kw[key])
    for key in tuples:
        kw[key] = tuple(kw[key])
    return TrainConfig(**kw)


@functools.cache
def _table_and_tuple_fields() -> tuple[tuple, tuple]:
    """TrainConfig's fields that are option objects ((name, class) pairs) and tuples (names)."""
    hints = _hints(TrainConfig)
    return (tuple((k, tp) for k, tp in hints.items() if dataclasses.is_dataclass(tp)),
            tuple(k for k, tp in hints.items() if typing.get_origin(tp) is tuple))


class TrainConfigs:
    """The training options of a manifest's scenes: ``preset`` (default fast) < the options given,
    each checked by TrainConfig.validate(), its whole numbers bounded and its backend named.
    TrainConfig.from_dict checks the types once per preset and shape of the options given (their
    keys and value types); scenes that differ only in values (seeds, step counts) reuse that check."""

    def __init__(self, file: Path):
        self.file = file
        self._bases: dict[str, dict] = {}
        self._typed: set = set()

    def __call__(self, options: dict, where: str) -> tuple[TrainConfig, dict]:
        """(the TrainConfig, its config.json dict) of a scene's (or the defaults') ``options``."""
        file = self.file
        given = {k: v for k, v in options.items() if k in TRAIN_KEYS}
        name = given.pop("preset", "fast")
        if not isinstance(name, str) or name not in PRESETS:
            raise UserError(f"unknown preset {name!r}; choose {', '.join(PRESETS)}", file=file,
                            field=f"{where}.preset")
        if name not in self._bases:
            self._bases[name] = preset(name).to_dict()
        base = self._bases[name]
        d = {**base, **given}
        for key, v in base.items():  # every scene its own tables; a given table changes the preset's key by key
            if isinstance(v, dict):
                mine = given.get(key, v)
                d[key] = {**v, **mine} if isinstance(mine, dict) else mine
        shape = (name, _shape(given))
        try:
            cfg = _construct(d) if shape in self._typed else TrainConfig.from_dict(d, source=str(file))
            self._typed.add(shape)
            cfg.validate()
        except UserError as exc:
            raise UserError(exc.detail, file=file, field=f"{where}.{exc.field}") from None
        except TypeError as exc:  # a value of a wrong type that from_dict's check let through
            raise UserError(f"invalid options ({exc})", file=file, field=where) from None
        _check_ints(given, TrainConfig, file, where)
        return cfg, d


def train_config(options: dict, file: Path, where: str) -> TrainConfig:
    """The TrainConfig of a scene: preset (``preset``, default fast) < the given options; validated."""
    return TrainConfigs(file)(options, where)[0]


def _product_value(key: str, v, file: Path, field: str):
    if key == "size":
        v = [v] if isinstance(v, int) else v
        if not (isinstance(v, list) and 1 <= len(v) <= 2
                and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in v)):
            raise UserError(f"expected a pixel count W or [W, H] (positive integers), got {v!r}", file=file,
                            field=field)
        return tuple(v)
    if key in ("check_decoder", "mcd43"):
        if not isinstance(v, bool):
            raise UserError(f"expected true or false, got {v!r}", file=file, field=field)
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise UserError(f"expected a number, got {v!r}", file=file, field=field)
    return float(v)


def _product_range(key: str, v, file: Path, field: str):
    """``v`` when ProductsOptions.validate() accepts it as option ``key`` (sun zeniths 0-89 deg, a
    positive extent, ...); UserError naming the field otherwise."""
    problem = _product_problem(key, v)
    if problem:
        raise UserError(problem, file=file, field=field)
    return v


@functools.lru_cache(maxsize=1024)
def _product_problem(key: str, v) -> str | None:
    try:
        ProductsOptions(**{key: v}).validate()
    except UserError as exc:
        return exc.detail
    return None


def products_options(value, variant: str, file: Path, where: str) -> dict | None:
    """The ProductsOptions fields of ``products`` (true, false, a table, or None: true for variant brf)."""
    field = f"{where}.products"
    if value is None:
        return {} if variant == "brf" else None
    if value is False:
        return None
    if variant != "brf":
        raise UserError(f"kernel products need variant 'brf' (this scene trains {variant!r}); set products = false",
                        file=file, field=field)
    if value is True:
        return {}
    if not isinstance(value, dict):
        raise UserError(f"expected true, false or a table of products options, got {value!r}", file=file, field=field)
    for key in value:
        if key not in PRODUCT_KEYS:
            raise _unknown(key, PRODUCT_KEYS, file, f"{field}.{key}")
    return {k: _product_range(k, _product_value(k, v, file, f"{field}.{k}"), file, f"{field}.{k}")
            for k, v in value.items()}


def _resources(options: dict, file: Path, where: str) -> tuple[int, float]:
    cpus, gpus = options.get("num_cpus", 1), options.get("num_gpus", 0)
    if isinstance(cpus, bool) or not isinstance(cpus, int) or not 1 <= cpus <= MAX_CPUS:
        raise UserError(f"expected a whole number of CPUs in 1..{MAX_CPUS}, got {cpus!r}", file=file,
                        field=f"{where}.num_cpus")
    if isinstance(gpus, bool) or not isinstance(gpus, (int, float)) or not 0 <= gpus <= MAX_GPUS:
        raise UserError(f"expected a number of GPUs in 0..{MAX_GPUS}, got {gpus!r}", file=file,
                        field=f"{where}.num_gpus")
    return cpus, float(gpus)


def _merge(defaults: dict, raw: dict) -> dict:
    """A scene's options: ``defaults`` < ``raw``; the tables ``densify`` and ``products`` merge key by key."""
    out = {**defaults, **raw}
    for key in ("densify", "mcmc", "products"):
        if isinstance(defaults.get(key), dict) and isinstance(raw.get(key), dict):
            out[key] = {**defaults[key], **raw[key]}
    return out


def _scene(i: int, raw: dict, defaults: dict, file: Path, out_root: Path, configs: TrainConfigs) -> BatchScene:
    where = f"scene[{i}]"
    _check_keys(raw, where, file, per_scene=True)
    path = raw.get("scene")
    if not isinstance(path, str) or not path:
        raise UserError("expected the scene folder's path", file=file, field=f"{where}.scene")
    scene = _absolute(file.parent, path)
    name = raw.get("name", scene.name)
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise UserError(f"expected a name of letters, digits, '.', '_' and '-', got {name!r}", file=file,
                        field=f"{where}.name")
    out = raw.get("out")
    if out is not None and not (isinstance(out, str) and out):
        raise UserError(f"expected a folder path, got {out!r}", file=file, field=f"{where}.out")
    options = _merge(defaults, raw)
    cpus, gpus = _resources(options, file, where)
    cfg, config = configs(options, where)
    return BatchScene(name=name, scene=scene, out=_absolute(file.parent, out) if out else out_root / name,
                      config=config, products=products_options(options.get("products"), cfg.variant, file, where),
                      num_cpus=cpus, num_gpus=gpus, index=i)


@dataclass(frozen=True)
class ManifestCheck:
    """A checked manifest: its valid scenes (``manifest``), the number of scenes it lists, and every
    problem found as (scene index, UserError) in manifest order (index 0: the manifest as a whole)."""

    manifest: Manifest
    total: int
    problems: list[tuple[int, UserError]]


def check_manifest(path: str | Path, out: str | Path | None = None) -> ManifestCheck:
    """Read a manifest and check every scene (options, paths), collecting each scene's problem instead of
    stopping at the first; ``out`` (``--out``) overrides its output root. A problem of the manifest as a
    whole (unreadable, bad defaults) is raised."""
    file = _absolute(Path.cwd(), path)
    out_key, defaults, raw_scenes = _sections(load_manifest_data(file), file)
    _check_keys(defaults, "defaults", file, per_scene=False)
    _resources(defaults, file, "defaults")
    configs = TrainConfigs(file)
    cfg, _ = configs(defaults, "defaults")
    products_options(defaults.get("products"), cfg.variant, file, "defaults")
    if out is not None:
        out_root = _absolute(Path.cwd(), out)
    else:
        out_root = _absolute(file.parent, out_key) if out_key else file.parent / f"{file.stem}_batch"
    scenes, problems = [], []
    for i, raw in enumerate(raw_scenes, 1):
        try:
            scenes.append(_scene(i, raw, defaults, file, out_root, configs))
        except UserError as exc:
            problems.append((i, exc))
    path_problems = check_paths(scenes, out_root, file, Resolver(file))
    bad = {i for i, _ in path_problems}
    problems = sorted(problems + path_problems, key=lambda p: p[0])
    return ManifestCheck(Manifest(path=file, out=out_root, scenes=[s for s in scenes if s.index not in bad]),
                         len(raw_scenes), problems)


def read_manifest(path: str | Path, out: str | Path | None = None) -> Manifest:
    """Read and validate a manifest (:func:`check_manifest`); its first problem is raised, saying how
    many more there are. ``out`` (``--out``) overrides its output root."""
    check = check_manifest(path, out)
    if check.problems:
        first, more = check.problems[0][1], len(check.problems) - 1
        if more:
            raise UserError(f"{first.detail} (and {more} more: brfgs batch --dry-run lists every one)",
                            file=first.file, field=first.field)
        raise first
    return check.manifest
