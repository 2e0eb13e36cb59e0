"""Defaults, seeds and tolerances, each defined once (STYLE.md "one documented place for tolerances").

Stage configs (``SynthConfig``, ``RenderConfig``, ``GtConfig``, ``MapConfig``, ...) take these as their
defaults and the command line shows them in ``--help``; nothing reads them as mutable globals. A module
that needs one imports it from here; no other module writes the number again.

Command-line options are declared here too, on the config dataclasses' fields: :func:`option` is a
``dataclasses.field`` whose metadata (:class:`Opt`: help text with units, option name, range, choices)
``panovocc_cli.cli.options`` turns into the Typer command's parameters and checks.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import MISSING, dataclass
from typing import Any, Callable, Sequence

# --------------------------------------------------------------------------------------- defaults
DEFAULT_SEED = 0
"""Seed of every random choice (scene generator, render noise, simulated segmenter) unless given."""
MAX_SEED = 2 ** 64 - 1
"""Largest seed a command accepts (64 bits: what a seed option means everywhere; numpy would take any int)."""
DEFAULT_VOXEL_SIZE = 0.08
"""Voxel edge length h, metres: the paper's and ReplicaOcc/FreeOcc's resolution."""
MAX_VOXEL_SIZE = 10.0
"""Largest voxel edge a command accepts, metres."""
MAX_STRIDE = 64
"""Largest pixel stride of the mapper's kernel lift (a 1024-wide panorama keeps 16 samples around)."""
MAX_PICTURE_PX = 16384
"""Largest picture width in pixels (``show --width-px``)."""
DEFAULT_WIDTH = 1024
"""ERP width W in pixels (height = W / 2)."""
MIN_WIDTH = 64
"""Smallest ERP width in pixels a command accepts (a 64 x 32 panorama: 5.6 degrees a pixel)."""
NOISE_MODELS = ("none", "realistic")
"""Depth noise models of the renderer: none, or realistic (rendering/noise.py)."""
DEPTH_SCALE = 1000.0
"""uint16 depth PNG units per metre (millimetres)."""

# ------------------------------------------------------------------------------------- tolerances
RIGID_TOL = 1e-4
"""Largest |R Rᵀ − I| entry (and |last row − (0, 0, 0, 1)|) for a pose to count as rigid."""
LATTICE_TOL = 1e-4
"""Voxel units: how far ``origin / h − 0.5`` may be from whole numbers for a grid to lie on the lattice."""
VOXEL_SIZE_RTOL = 1e-6
"""Relative tolerance for two grids to have "the same voxel size"."""
GT_BOUNDARY_EPS = 1e-5
"""Voxel units: a mesh vertex this close below a voxel face counts as on it (float32 PLY coordinates)."""
SNAP_TOL = 0.25
"""Fraction of a voxel a ReplicaOcc voxel centre may be off the lattice and still be snapped onto it."""
COVERAGE_TOL_M = 0.01
"""Metres: a depth point this close to a voxel face also observes the voxel across it (coverage)."""
MAX_POSITION_M = 1e9
"""Metres: the largest camera coordinate a trajectory file may hold (a million km; squares of larger values
overflow the error statistics)."""
MATCH_MAX_DIFF = 0.01
"""Seconds (or frame indices): the largest timestamp difference of two matched trajectory poses (evo's default)."""
PROB_TOL = 1e-2
"""Precomputed segmenter probabilities: slack on [0, 1] and on their sum to 1."""


# ------------------------------------------------------------------------- command-line options
OPT_KEY = "panovocc_cli"
"""Key of a field's ``metadata`` that holds its :class:`Opt`."""


@dataclass(frozen=True)
class Opt:
    """How a config field appears on the command line (see :func:`option`)."""

    help: str
    flag: str | None = None
    argument: bool = False
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    choices: tuple[str, ...] | None = None
    even: bool = False
    cli_type: Any = None
    parse: Callable[[Any], Any] | None = None
    metavar: str | None = None
    negate: bool = False
    show_default: bool | str = True
    cli_optional: bool = False


def option(default: Any = MISSING, *, help: str, default_factory: Any = MISSING, flag: str | None = None,
           argument: bool = False, min: float | None = None, max: float | None = None, min_open: bool = False,
           choices: Sequence[str] | None = None, even: bool = False, cli_type: Any = None,
           parse: Callable[[Any], Any] | None = None, metavar: str | None = None, negate: bool = False,
           show_default: bool | str = True, cli_optional: bool = False) -> Any:
    """A ``dataclasses.field`` that is also a command-line parameter.

    Parameters
    ----------
    default, default_factory : as for ``dataclasses.field`` (no default: a required argument/option)
    help : the ``--help`` text, with the unit of the value
    flag : the option's name (default ``--field-name``)
    argument : a positional argument instead of an option
    min, max : inclusive bounds of a number (``min_open``: ``min`` itself excluded)
    choices : the accepted strings (compared after ``strip().lower()``)
    even : an integer that must be even (ERP widths)
    cli_type : the type typed on the command line when it differs from the field's (``parse`` converts)
    parse : callable turning the command-line value into the field's value (None stays None)
    metavar : the name shown for an argument's value
    negate : a bool field set by a flag that means "not" (``--no-gsc`` sets ``use_gsc=False``)
    show_default : False, or a text shown in place of the default
    cli_optional : a field without a default that the command line may leave out (None; the command
        decides, e.g. ``map --resume OUT`` without SEQ)
    """
    meta = {OPT_KEY: Opt(help=help, flag=flag, argument=argument, min=min, max=max, min_open=min_open,
                         choices=tuple(choices) if choices is not None else None, even=even, cli_type=cli_type,
                         parse=parse, metavar=metavar, negate=negate, show_default=show_default,
                         cli_optional=cli_optional)}
    if default_factory is not MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def option_name(field_name: str, o: Opt) -> str:
    """How the user types a field: its option (``--voxel-size``) or, for an argument, its metavar (``SEQ``)."""
    if o.argument:
        return o.metavar or field_name.upper()
    return o.flag or "--" + field_name.replace("_", "-")


def _bound(x) -> str:
    """A bound as typed: an int in full (``18446744073709551615``), a float short (``10``, ``0.001``)."""
    return str(x) if isinstance(x, int) and not isinstance(x, bool) else f"{x:g}"


def bounds_words(o: Opt) -> str:
    """The declared range in words: ``> 0 and <= 10``."""
    lo = None if o.min is None else f"{'>' if o.min_open else '>='} {_bound(o.min)}"
    hi = None if o.max is None else f"<= {_bound(o.max)}"
    return " and ".join(t for t in (lo, hi) if t)


def check_option(name: str, o: Opt, value: Any) -> Any:
    """``value`` checked against the declared choices, range and parity of an option called ``name``.

    The one place where declared ranges are enforced: the command line (cli/options.py) and
    :func:`validate_config` (every ``run_*``, for Python API users) both call it.

    Returns
    -------
    The value, a choice normalised with ``strip().lower()``.

    Raises
    ------
    PanovoccError
        One line naming the option: not one of the choices, not a number, NaN or infinite (for every
        numeric option, declared range or not), outside the range, odd.
    """
    from .errors import PanovoccError

    if value is None or isinstance(value, bool):
        return value
    if o.choices is not None:
        v = value.strip().lower() if isinstance(value, str) else value
        if v not in o.choices:
            raise PanovoccError(f"{name}: {value!r} is not one of {', '.join(o.choices)}")
        return v
    if isinstance(value, float) or (hasattr(value, "dtype") and value.dtype.kind == "f"):
        if not math.isfinite(value):  # NaN or an infinity: no option means anything by them
            raise PanovoccError(f"{name} must be a finite number, got {value}")
    if o.min is None and o.max is None and not o.even:
        return value
    if not isinstance(value, (int, float)) and not (hasattr(value, "dtype") and value.dtype.kind in "iuf"):
        raise PanovoccError(f"{name} must be a number, got {value!r}")
    lo_bad = o.min is not None and (value <= o.min if o.min_open else value < o.min)
    if lo_bad or (o.max is not None and value > o.max):
        shown = value if isinstance(value, int) else f"{float(value):g}"
        raise PanovoccError(f"{name} must be {bounds_words(o)}, got {shown}")
    if o.even and int(value) % 2:
        raise PanovoccError(f"{name} must be even, got {value}")
    return value


def validate_config(cfg: Any) -> Any:
    """Check every declared option of a stage config (and of its nested configs) against its declaration.

    The ranges, choices and parity written on the fields with :func:`option` are the only ones: each
    ``run_*`` calls this first, so a Python API user gets the same one-line :class:`PanovoccError`
    as the command line, before any work or write.

    Parameters
    ----------
    cfg : a config dataclass instance (``MapConfig``, ``RenderConfig``, ...)

    Returns
    -------
    ``cfg``, or a copy with choices normalised (``" Realistic"`` -> ``"realistic"``).
    """
    changes = {}
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        o = f.metadata.get(OPT_KEY)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            new = validate_config(value)
        elif o is not None and not o.negate:
            new = check_option(option_name(f.name, o), o, value)
        else:
            continue
        if new is not value:
            changes[f.name] = new
    return dataclasses.replace(cfg, **changes) if changes else cfg


def typed_from_json(cls, d: dict, section: str | None = None):
    """``cls(**d)`` for a dataclass whose fields all have defaults, each value checked against the type of
    the field's default (an int accepted for a float); raises TypeError naming the bad key or value
    (``section``: the name used for the object, default the class name)."""
    name = section or cls.__name__
    if not isinstance(d, dict):
        raise TypeError(f"{name} section is {type(d).__name__}, expected an object")
    defaults = cls()
    for k, v in d.items():
        if not hasattr(defaults, k):
            raise TypeError(f"unknown {name} key {k!r}")
        want = type(getattr(defaults, k))
        if not (type(v) is want or (want is float and type(v) is int)):
            raise TypeError(f"{k} is {v!r}, expected {want.__name__}")
    return cls(**d)
