"""The config of ``panovocc gt``, in a module that imports nothing heavy (no numba: ``--help`` builds the
command line from it and stays instant). :mod:`panovocc_cli.gt` re-exports :class:`GtConfig`.

Two ground truths share the command: the mesh one (``gt SCENE OUT``, :mod:`panovocc_cli.gt.mesh`) and the
one lifted from a capture (``gt --from-sequence SEQ OUT``, :mod:`panovocc_cli.gt.lifted`), whose protocol
knobs are :class:`LiftParams` (docs/gt.md gives the measurements behind each default).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .config import DEFAULT_VOXEL_SIZE, MAX_VOXEL_SIZE, option

DEFAULT_ANNOTATED = "every:10"
"""Annotated frames of a lifted ground truth unless given: every 10th frame (0, 10, 20, ...)."""
DEFAULT_MIN_FRAMES = 2
"""A consensus surface voxel is occupied when at least this many frames' points support it (docs/gt.md)."""
DEFAULT_MIN_POINTS = 3
"""A surface mode of a column needs at least this many points within one voxel of it (docs/gt.md)."""
DEFAULT_MIN_HIT_RATIO = 0.25
"""A consensus surface voxel is occupied when the frames supporting it are at least this fraction of the frames
supporting it or seeing through it (docs/gt.md)."""
DEFAULT_SURFACE_TOL = 0.08
"""Metres: a point supports (or, farther behind, sees through) a consensus surface within tol(r) =
surface_tol + surface_tol_r2 r^2 of it along its normal axis (docs/gt.md)."""
DEFAULT_SURFACE_TOL_R2 = 0.004
"""Metres per square metre of range: the range-dependent part of tol(r) (docs/gt.md)."""
DEFAULT_LABEL_RADIUS = 0.16
"""Metres: an occupied voxel no annotation reached takes the most common label of the nearest labelled voxels
this close, those on its own surface first (centre to centre, two voxels at 8 cm), else 254 (docs/gt.md)."""


@dataclass
class LiftParams:
    """The lifting protocol's knobs (``gt --from-sequence``): annotated frames, the consensus rules, label radius."""

    annotated: str = option(DEFAULT_ANNOTATED, metavar="every:K|all|none|I,J,...",
                            help="Frames whose label PNG (SEQ/semantic/) is lifted: every:K (0, K, 2K, ...), all, "
                                 "none, or a comma list of frame numbers.")
    min_points: int = option(DEFAULT_MIN_POINTS, min=1,
                             help="A surface mode of a voxel column needs at least this many depth points within one "
                                  "voxel of it ...")
    min_frames: int = option(DEFAULT_MIN_FRAMES, min=1,
                             help="... its voxel is occupied when points of at least this many frames support it ...")
    min_hit_ratio: float = option(DEFAULT_MIN_HIT_RATIO, min=0, max=1,
                                  help="... and the frames supporting it are at least this fraction of those "
                                       "supporting it or seeing through it.")
    surface_tol: float = option(DEFAULT_SURFACE_TOL, min=0,
                                help="Metres: a point supports a consensus surface within surface_tol + "
                                     "surface_tol_r2 * range^2 of it along its normal; a ray whose point lies "
                                     "farther behind it sees through it.")
    surface_tol_r2: float = option(DEFAULT_SURFACE_TOL_R2, min=0,
                                   help="Metres per square metre of range: the range-dependent part of that tolerance.")
    label_radius: float = option(DEFAULT_LABEL_RADIUS, min=0, max=MAX_VOXEL_SIZE * 10,
                                 help="Metres: an occupied voxel no annotation reached takes the most common label "
                                      "of the nearest labelled voxels within this distance (voxel centres), those "
                                      "on its own surface first, else 254.")
    max_range: float = option(0.0, min=0, help="Metres: ignore depth beyond this range (0 = keep all).")


@dataclass
class GtConfig:
    """Options of ``panovocc gt``: scene (Replica-format folder) or from_sequence (a captured sequence),
    out (.npz), voxel_size (metres), lift (the lifting protocol), overwrite."""

    scene: Path | None = option(argument=True, metavar="SCENE", cli_optional=True,
                                help="Replica-format scene folder (omit with --from-sequence).")
    out: Path | None = option(argument=True, metavar="OUT", cli_optional=True,
                              help="Ground-truth grid to write (.npz: labels, origin, voxel_size, class_names).")
    from_sequence: Path | None = option(None, metavar="SEQ",
                                        help="Build the ground truth from a captured sequence instead of a mesh: "
                                             "occupancy from every frame's depth, classes lifted from the "
                                             "annotated frames' labels (docs/gt.md).")
    voxel_size: float = option(DEFAULT_VOXEL_SIZE, min=0, min_open=True, max=MAX_VOXEL_SIZE,
                               help="Voxel edge length in metres.")
    lift: LiftParams = field(default_factory=LiftParams)
    progress: bool = True
    overwrite: bool = option(False, help="Replace an existing OUT file (never an input).")


@dataclass
class S2d3dsGtConfig:
    """Options of ``panovocc convert s2d3ds-gt``."""

    annotations: Path = option(argument=True, metavar="AREA_DIR",
                               help="An S3DIS area folder: ROOM/Annotations/<class>_<k>.txt (x y z r g b a line).")
    out: Path = option(argument=True, metavar="GT.npz", help="Ground-truth grid to write (and GT.config.json beside it).")
    voxel_size: float = option(DEFAULT_VOXEL_SIZE, min=0.0, min_open=True, help="Voxel edge in metres.")
    rooms: str | None = option(None, help="Comma-separated rooms to use (e.g. office_1,office_2; default all).",
                               show_default=False)
    progress: bool = True
    overwrite: bool = option(False, help="Replace an existing grid file.")
