"""Mapping: the streaming :class:`Mapper` (frames from memory -> semantic occupancy grid), its config
(``config``), the reversible per-frame delta store (``rpu``), the hashed voxel memory, the per-frame
contributors (the PSVF kernel and free-space carving, the semantic evidence), export, and the ``map`` /
``revise`` run loops (``pipeline``).

numba's threading layer is chosen in ``panovocc_cli/__init__.py`` (OpenMP first, never TBB first)."""

from __future__ import annotations

from ..frame import Frame

__all__ = ["Frame", "Mapper", "MapperConfig"]


def __getattr__(name: str):
    # the Mapper pulls in numba kernels: imported on first use, so `import panovocc_cli.mapping.params`
    # (the CLI's --help) stays light
    if name == "Mapper":
        from .mapper import Mapper

        return Mapper
    if name == "MapperConfig":
        from .config import MapperConfig

        return MapperConfig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
