"""Command options declared once, on the stage's config dataclass, and turned into Typer parameters here.

A config field becomes a command-line parameter when its ``metadata`` carries an
:class:`~panovocc_cli.config.Opt` (use :func:`panovocc_cli.config.option` in place of
``dataclasses.field``; it lives beside the defaults so that library modules declare options without
importing Typer)::

    @dataclass
    class SynthConfig:
        out: Path = option(help="Scene folder to write.", argument=True, metavar="SCENE")
        seed: int = option(DEFAULT_SEED, help="Random seed; the same seed gives the same files.", min=0)

The help text (with units), the option's name, its range or choices are written there and nowhere else.
:func:`config_command` builds the Typer command's signature from those fields (``inspect.Signature``
with ``typer.Option`` / ``typer.Argument`` defaults), adds the command function's own parameters (those
that are not config fields: ``--quiet``, ``--overwrite``, ``--json``, a list of paths), and before the
command body runs it checks every value against its declared range and choices: a bad value is one
:class:`~panovocc_cli.errors.PanovoccError` line (exit 2) before any work or write.

The command function receives the checked values as its first argument, an :class:`OptionValues`
(a dict of field name -> value, with ``.given``: the names the user set on the command line), then its
own parameters by keyword.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from dataclasses import MISSING, dataclass
from typing import Any, Callable, Optional, Sequence

import typer

from ..config import OPT_KEY, Opt, check_option, option_name


class OptionValues(dict):
    """Checked option values by field name; ``given`` holds the names set on the command line, ``flags``
    each name's option (``--voxel-size``) or argument (``SEQ``) as the user types it."""

    given: frozenset = frozenset()
    flags: dict = {}


@dataclass(frozen=True)
class _Spec:
    name: str  # the Python parameter name (unique in the command)
    field: str  # the dataclass field name
    type: Any
    default: Any
    opt: Opt


def _unwrap_optional(tp: Any) -> tuple[Any, bool]:
    """``X | None`` / ``Optional[X]`` -> (X, True); anything else -> (tp, False)."""
    args = typing.get_args(tp)
    if args and type(None) in args and (typing.get_origin(tp) is typing.Union or type(tp).__name__ == "UnionType"):
        rest = [a for a in args if a is not type(None)]
        if len(rest) == 1:
            return rest[0], True
    return tp, False


def option_specs(config_cls: type, only: Sequence[str] | None = None, exclude: Sequence[str] = ()) -> list[_Spec]:
    """The command-line fields of a config dataclass, in declaration order."""
    hints = typing.get_type_hints(config_cls)
    specs = []
    for f in dataclasses.fields(config_cls):
        o = f.metadata.get(OPT_KEY)
        if o is None or f.name in exclude or (only is not None and f.name not in only):
            continue
        if f.default is not MISSING:
            default = f.default
        elif f.default_factory is not MISSING:
            default = f.default_factory()
        else:
            default = None if o.cli_optional else ...
        specs.append(_Spec(f.name, f.name, hints[f.name], default, o))
    return specs


def _flag(spec: _Spec) -> str:
    return option_name(spec.field, spec.opt)


def _bound(v) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"  # integers in full (a seed's 2^64 - 1, not 1.84467e+19)


def _range_text(o: Opt) -> str:
    parts = []
    if o.min is not None and o.max is not None:
        parts.append(f"{_bound(o.min)} {'<' if o.min_open else '<='} x <= {_bound(o.max)}")
    elif o.min is not None:
        parts.append(f"x {'>' if o.min_open else '>='} {_bound(o.min)}")
    elif o.max is not None:
        parts.append(f"x <= {_bound(o.max)}")
    if o.even:
        parts.append("even")
    return f" (range: {', '.join(parts)})" if parts else ""  # not [..]: rich would read it as markup


def _help(spec: _Spec) -> str:
    o = spec.opt
    text = o.help + _range_text(o)
    if o.choices and not all(c in o.help for c in o.choices):
        text += f" ({' | '.join(o.choices)})"
    return text


def _typer_param(spec: _Spec) -> tuple[Any, Any]:
    """(annotation, typer.Option/Argument default) of one field."""
    o = spec.opt
    base, optional = _unwrap_optional(spec.type)
    cli_type = o.cli_type if o.cli_type is not None else base
    if o.negate:
        return bool, typer.Option(False, _flag(spec), help=o.help, show_default=False)
    default = spec.default
    kw: dict[str, Any] = {"help": _help(spec)}
    if o.show_default is not True:
        kw["show_default"] = o.show_default
    if o.cli_type is not None and default is not None and default is not ...:
        kw.setdefault("show_default", str(default))  # the field keeps its own default (see check_value)
        default, optional = None, True
    ann = Optional[cli_type] if (optional or default is None) else cli_type
    if o.metavar:
        kw["metavar"] = o.metavar
    if o.argument:
        return ann, typer.Argument(default, **kw)
    if cli_type is bool:
        return bool, typer.Option(bool(default), _flag(spec), **kw)
    return ann, typer.Option(default, _flag(spec), **kw)


def check_value(spec: _Spec, value: Any) -> Any:
    """The field's value for a command-line ``value``; :class:`PanovoccError` outside the declared range."""
    o = spec.opt
    if o.negate:
        return not value
    if value is None or value is ...:
        return spec.default if o.cli_type is not None else value
    value = check_option(option_name(spec.field, o), o, value)
    if o.parse is not None:
        value = o.parse(value)
    return value


def config_command(app: typer.Typer, config_cls: type, name: str | None = None, *,
                   only: Sequence[str] | None = None, exclude: Sequence[str] = (),
                   nested: Sequence[str] = (), **command_kwargs) -> Callable[[Callable], Callable]:
    """Register the decorated function as the Typer command ``name`` with ``config_cls``'s options.

    Parameters
    ----------
    app : the Typer app (or sub-app) to register on
    config_cls : the stage's config dataclass; its :func:`option` fields become parameters
    only, exclude : restrict the fields used
    nested : names of fields that are themselves config dataclasses whose options are flattened into
        the command (values arrive under the inner field names)
    command_kwargs : passed on to ``app.command``

    The function's first parameter receives an :class:`OptionValues`; its other parameters (declared
    the Typer way) are kept as they are.
    """

    def deco(fn: Callable) -> Callable:
        specs = option_specs(config_cls, only, exclude)
        hints = typing.get_type_hints(config_cls)
        for n in nested:
            specs += option_specs(_unwrap_optional(hints[n])[0])
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"{config_cls.__name__}: duplicate option names {names}")
        own = list(inspect.signature(fn).parameters.values())[1:]
        own_hints = typing.get_type_hints(fn)
        clash = {p.name for p in own} & set(names)
        if clash:
            raise ValueError(f"{fn.__name__}: parameters {sorted(clash)} are also config fields")
        gen = {}
        for s in specs:
            gen[s.name] = _typer_param(s)
        params, annotations = [], {}

        def add(pname, ann, default):
            params.append(inspect.Parameter(pname, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=ann))
            annotations[pname] = ann

        is_arg = lambda d: isinstance(d, typer.models.ArgumentInfo)  # noqa: E731
        for s in specs:  # arguments first (config fields, then the function's own), then options
            if is_arg(gen[s.name][1]):
                add(s.name, *gen[s.name])
        for p in own:
            if is_arg(p.default):
                add(p.name, own_hints.get(p.name, p.annotation), p.default)
        for s in specs:
            if not is_arg(gen[s.name][1]):
                add(s.name, *gen[s.name])
        for p in own:
            if not is_arg(p.default):
                add(p.name, own_hints.get(p.name, p.annotation), p.default)
        add("_ctx", typer.Context, inspect.Parameter.empty)

        def command(**kwargs):
            ctx = kwargs.pop("_ctx")
            values = OptionValues()
            given = set()
            for s in specs:
                raw = kwargs.pop(s.name)
                src = ctx.get_parameter_source(s.name)
                if src is not None and src.name not in ("DEFAULT", "DEFAULT_MAP"):
                    given.add(s.name)
                values[s.field] = check_value(s, raw)
            values.given = frozenset(given)
            values.flags = {s.field: (s.opt.metavar or s.field.upper()) if s.opt.argument else _flag(s) for s in specs}
            return fn(values, **kwargs)

        # the context parameter goes first for Typer; the rest keep their order
        ctx_param = params.pop()
        command.__signature__ = inspect.Signature([ctx_param.replace(kind=inspect.Parameter.POSITIONAL_OR_KEYWORD)]
                                                  + params)
        command.__annotations__ = {**annotations, "return": None}
        command.__name__ = fn.__name__
        command.__doc__ = fn.__doc__
        command.__module__ = fn.__module__
        app.command(name, **command_kwargs)(command)
        return fn

    return deco


def build_config(config_cls: type, values: dict, **extra) -> Any:
    """``config_cls(**extra, **options)``: the values of ``config_cls``'s own command-line fields taken from
    ``values`` (the flattened options of a command with nested configs), the rest from ``extra``."""
    own = {s.field for s in option_specs(config_cls)}
    return config_cls(**{k: v for k, v in values.items() if k in own}, **extra)
