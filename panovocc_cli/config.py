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
from dataclasses import MISSING, dataclass
from typing import Any, Callable, Sequence

# --------------------------------------------------------------------------------------- defaults
DEFAULT_SEED = 0
"""Seed of every random choice (scene generator, render noise, simulated segmenter) unless given."""
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
MIN_WIDTH = 64
"""Pixels: the narrowest ERP image render, bench and demo accept (a 64 x 32 panorama, 5.6 degrees a pixel)."""
MAX_STRIDE = 64
"""Pixels: the largest kernel-lift stride map accepts (a larger one leaves nothing to map)."""
MAX_PICTURE_PX = 16384
"""Pixels: the widest picture show writes."""

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
