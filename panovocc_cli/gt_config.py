"""The config of ``panovocc gt``, in a module that imports nothing heavy (no numba: ``--help`` builds the
command line from it and stays instant). :mod:`panovocc_cli.gt` re-exports :class:`GtConfig`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .config import DEFAULT_VOXEL_SIZE, MAX_VOXEL_SIZE, option


@dataclass
class GtConfig:
    """Options of ``panovocc gt``: scene (Replica-format folder), out (.npz), voxel_size (metres), overwrite."""

    scene: Path = option(argument=True, metavar="SCENE", help="Replica-format scene folder.")
    out: Path = option(argument=True, metavar="OUT",
                       help="Ground-truth grid to write (.npz: labels, origin, voxel_size, class_names).")
    voxel_size: float = option(DEFAULT_VOXEL_SIZE, min=0, min_open=True, max=MAX_VOXEL_SIZE,
                               help="Voxel edge length in metres.")
    overwrite: bool = option(False, help="Replace an existing OUT file (never an input).")
