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
"""Minimum support of a lifted occupied voxel: depth points from at least this many frames (docs/gt.md)."""
DEFAULT_MIN_POINTS = 3
"""Minimum support of a lifted occupied voxel: at least this many depth points in all (docs/gt.md)."""
DEFAULT_MIN_HIT_RATIO = 0.2
"""Minimum support of a lifted occupied voxel: frames hitting it / (frames hitting it + frames seeing through
it) at least this (docs/gt.md)."""
DEFAULT_LABEL_RADIUS = 0.16
"""Metres: an occupied voxel no annotation reached takes the label of the nearest labelled voxel this close
(centre to centre, two voxels at 8 cm), else 254 (docs/gt.md)."""


@dataclass
class LiftParams:
    """The lifting protocol's knobs (``gt --from-sequence``): annotated frames, minimum support, label radius."""

    annotated: str = option(DEFAULT_ANNOTATED, metavar="every:K|all|none|I,J,...",
                            help="Frames whose label PNG (SEQ/semantic/) is lifted: every:K (0, K, 2K, ...), all, "
                                 "none, or a comma list of frame numbers.")
    min_frames: int = option(DEFAULT_MIN_FRAMES, min=1,
                             help="Minimum support: a voxel is occupied when depth points of at least this many "
                                  "frames fall in it ...")
    min_points: int = option(DEFAULT_MIN_POINTS, min=1, help="... and at least this many points in all ...")
    min_hit_ratio: float = option(DEFAULT_MIN_HIT_RATIO, min=0, max=1,
                                  help="... and the frames hitting it are at least this fraction of those hitting it "
                                       "or seeing through it.")
    label_radius: float = option(DEFAULT_LABEL_RADIUS, min=0, max=MAX_VOXEL_SIZE * 10,
                                 help="Metres: an occupied voxel no annotation reached takes the nearest lifted "
                                      "label within this distance (voxel centres), else 254.")
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
