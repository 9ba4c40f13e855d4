"""Command-line options generated from a config dataclass (one source of truth).

:func:`config_command` adds one ``--option`` per field of a dataclass (nested dataclasses
flattened: ``densify.refine_every`` is ``--densify-refine-every``), typed from the field, with
the field's ``metadata["help"]`` as help and ``metadata["flag"]`` as an explicit flag
(e.g. ``--joint/--decoupled``). Every generated option defaults to None, meaning "not given", so
the command can layer preset < config file < options (:func:`apply_options`); a field without a
default is a required option.

Other metadata keys: ``panel`` (the heading the option is listed under in ``--help``), ``expert``
(True: listed only by ``--help-all``, under "Experimental and expert options"), ``aliases`` (short
flags such as ``("-o",)``) and ``metavar``. Every field's help is one line of product terms; the
reasons and measurements behind a setting are in the documentation.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Callable, Optional

import typer

from brfgs.errors import UserError


@dataclasses.dataclass(frozen=True)
class ConfigOption:
    """One generated option: the field path (``("densify", "refine_every")``), its type and flag."""

    path: tuple[str, ...]
    kind: Any
    flag: str
    help: str
    panel: str | None = None
    expert: bool = False
    aliases: tuple[str, ...] = ()
    metavar: str | None = None
    required: bool = False
    default: Any = None

    @property
    def name(self) -> str:
        return "_".join(self.path)


def _unoptional(tp):
    """``X`` of ``Optional[X]`` (``tp`` itself otherwise)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp):
        (tp,) = [a for a in typing.get_args(tp) if a is not type(None)]
    return tp


def _kind(tp) -> Any:
    """The click-facing type of a field: bool, int, float, str, Path; tuples are given as 'A,B,...' text."""
    tp = _unoptional(tp)
    if tp in (bool, int, float, str, Path):
        return tp
    if typing.get_origin(tp) is tuple:
        return str
    raise TypeError(f"no command-line type for {tp!r}")


def config_options(cls, prefix: tuple[str, ...] = (), flag_prefix: tuple[str, ...] = ()) -> list[ConfigOption]:
    """The options of every field of dataclass ``cls`` (nested dataclasses flattened: their fields'
    flags carry the nested field's name, ``--densify-refine-every``, unless its metadata says
    ``flatten``, as for options shared by several commands)."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        path = prefix + (f.name,)
        if dataclasses.is_dataclass(tp):
            out += config_options(tp, path, flag_prefix + (() if f.metadata.get("flatten") else (f.name,)))
            continue
        flag = f.metadata.get("flag") or "--" + "-".join(flag_prefix + (f.name,)).replace("_", "-")
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        default = None if required else (f.default if f.default is not dataclasses.MISSING else f.default_factory())
        out.append(ConfigOption(path, _kind(tp), flag, f.metadata.get("help", ""), f.metadata.get("panel"),
                                bool(f.metadata.get("expert", False)), tuple(f.metadata.get("aliases", ())),
                                f.metadata.get("metavar"), required, default))
    return out


def _parse_tuple(text: str, tp, option: ConfigOption) -> tuple:
    """'A,B,...' -> tuple of the field's item type; UserError naming the option when malformed."""
    args = typing.get_args(tp)
    item = args[0]
    parts = [p.strip(" ") for p in str(text).split(",") if p.strip(" ")]
    try:
        vals = tuple(_item(p, item) for p in parts)
    except (ValueError, typer.BadParameter):
        raise UserError(f"expected comma-separated {item.__name__} values, got {str(text)[:80]!r}",
                        field=option.flag) from None
    fixed = not (len(args) == 2 and args[1] is Ellipsis)
    if fixed and len(vals) != len(args) or not vals:
        raise UserError(f"expected {len(args) if fixed else 'one or more'} comma-separated values, got {text!r}",
                        field=option.flag)
    if item is float and not all(math.isfinite(v) for v in vals):
        raise UserError(f"expected finite numbers, got {text!r}", field=option.flag)
    return vals


def _item(text: str, item: type):
    """One item of a tuple option: numbers through :func:`parse_number`, text as it is."""
    return parse_number(text, item) if item in (int, float) else item(text)


def _field_type(cls, path: tuple[str, ...]):
    tp = cls
    for name in path:
        tp = typing.get_type_hints(tp)[name]
    return tp


def given_options(cls, values: dict[str, Any]) -> dict[tuple[str, ...], Any]:
    """{field path: parsed value} of the generated options that were given (not None)."""
    out = {}
    for opt in config_options(cls):
        v = values.get(opt.name)
        if v is None:
            continue
        tp = _unoptional(_field_type(cls, opt.path))
        out[opt.path] = _parse_tuple(v, tp, opt) if typing.get_origin(tp) is tuple else v
    return out


def apply_options(config, given: dict[tuple[str, ...], Any]):
    """``config`` (a dataclass instance) with the fields in ``given`` replaced (nested paths too)."""
    top: dict[str, Any] = {}
    nested: dict[str, dict[tuple[str, ...], Any]] = {}
    for path, v in given.items():
        if len(path) == 1:
            top[path[0]] = v
        else:
            nested.setdefault(path[0], {})[path[1:]] = v
    for name, sub in nested.items():
        top[name] = apply_options(getattr(config, name), sub)
    return dataclasses.replace(config, **top)


def read_config_file(path: Path) -> dict:
    """A config.json written by a run (a JSON object); UserError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise UserError("config file not found", file=path)
    from brfgs.data.validation import read_json_file

    data = read_json_file(path, "config file")
    if not isinstance(data, dict):
        raise UserError("expected a JSON object of training options", file=path)
    return data


EXPERT_PANEL = "Experimental and expert options"


def _show_all_help(ctx: typer.Context, _param, value: bool) -> None:
    """``--help-all``: the command's help with the expert options listed too."""
    if not value or ctx.resilient_parsing:
        return
    for p in ctx.command.params:
        p.hidden = False
    typer.echo(ctx.get_help())
    raise typer.Exit()


def _default_text(o: ConfigOption) -> str:
    """' (default: X)' for the help of an option whose dataclass default is worth showing."""
    d = o.default
    if d is None or o.required or d == "" or (isinstance(d, bool) and "/" in o.flag):
        return ""
    if isinstance(d, bool):
        return "" if not d else " (default: on)"
    text = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in d) if isinstance(d, tuple) else (
        f"{d:g}" if isinstance(d, float) else str(d))
    return f" (default: {text})"


_INTEGER = re.compile(r"[+-]?[0-9]+")
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def parse_number(text, kind: type):
    """A number option's text as ``kind`` (int or float): ASCII digits only (Python's int()/float()
    would read other scripts' digits, '1_000' and surrounding blanks), finite, at most 30 characters;
    typer.BadParameter (one line naming the option, brfgs.cli.main) otherwise."""
    if isinstance(text, kind) and not isinstance(text, bool):
        return text
    pattern, what = (_INTEGER, "an integer") if kind is int else (_DECIMAL, "a number")
    if not isinstance(text, str) or len(text) > 30 or not pattern.fullmatch(text):
        raise typer.BadParameter(f"expected {what} written with the digits 0-9, got {str(text)[:40]!r}")
    value = kind(text)
    if kind is float and not math.isfinite(value):
        raise typer.BadParameter(f"expected a finite number, got {text!r}")
    return value


def _option_parameter(o: ConfigOption) -> inspect.Parameter:
    """The keyword parameter (a typer.Option) of a generated option; numbers are read by
    :func:`parse_number`."""
    annotation = o.kind if o.required else Optional[o.kind]
    number = {"parser": (lambda text, kind=o.kind: parse_number(text, kind))} if o.kind in (int, float) else {}
    option = typer.Option(... if o.required else None, o.flag, *o.aliases, help=o.help + _default_text(o),
                          show_default=False, **number,
                          metavar=o.metavar, hidden=o.expert, rich_help_panel=EXPERT_PANEL if o.expert else o.panel)
    return inspect.Parameter(o.name, inspect.Parameter.KEYWORD_ONLY, annotation=annotation, default=option)


def config_command(app: typer.Typer, name: str, cls, *, skip: tuple[str, ...] = ()) -> Callable:
    """Decorator registering ``fn`` as command ``name`` with its own parameters plus one option
    per field of ``cls`` (except ``skip``); ``fn`` receives the given ones as ``options``
    ({field path: value}, see :func:`given_options`). When some fields are ``expert``, a
    ``--help-all`` option lists them (``--help`` does not)."""

    def deco(fn: Callable) -> Callable:
        opts = [o for o in config_options(cls) if o.name not in skip]
        own = [p for p in inspect.signature(fn).parameters.values() if p.name != "options"]
        hints = typing.get_type_hints(fn)
        params = [p.replace(annotation=hints.get(p.name, p.annotation)) for p in own]
        params += [_option_parameter(o) for o in opts]
        if any(o.expert for o in opts):
            params.append(inspect.Parameter("help_all", inspect.Parameter.KEYWORD_ONLY, annotation=bool, default=typer.Option(
                False, "--help-all", is_eager=True, expose_value=False, callback=_show_all_help,
                help="Show this message with the experimental and expert options, and exit.")))
        own_names = {p.name for p in own}

        def command(**kwargs):
            mine = {k: v for k, v in kwargs.items() if k in own_names}
            return fn(**mine, options=given_options(cls, {k: v for k, v in kwargs.items() if k not in own_names}))

        command.__name__ = fn.__name__
        command.__doc__ = fn.__doc__
        command.__signature__ = inspect.Signature(params)
        command.__annotations__ = {p.name: p.annotation for p in params}
        app.command(name)(command)
        return fn

    return deco
