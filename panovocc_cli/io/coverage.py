"""The coverage table of ``panovocc coverage``: ``coverage.csv``.

Columns ``frame,panoramic,perspective``: the frame index (int) and the cumulative fractions in [0, 1]
of the ground truth's occupied voxels observed so far by the panorama and by the forward perspective
camera, six decimals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from .atomic import write_text

HEADER = "frame,panoramic,perspective"


def write_coverage_csv(path: str | Path, frames, panoramic, perspective) -> None:
    """Atomically write the table; ``frames`` (n,) int, ``panoramic``/``perspective`` (n,) float fractions."""
    lines = [HEADER] + [f"{int(f)},{float(a):.6f},{float(b):.6f}" for f, a, b in zip(frames, panoramic, perspective)]
    write_text(path, "\n".join(lines) + "\n")


def read_coverage_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Read a table written by :func:`write_coverage_csv`.

    Returns
    -------
    {"frame": (n,) int64, "panoramic": (n,) float64, "perspective": (n,) float64}
    """
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("coverage CSV not found", path)
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
        if not lines or lines[0].strip() != HEADER:
            raise ValueError(f"first line is not {HEADER!r}")
        rows = [ln.split(",") for ln in lines[1:]]
        frames = np.array([int(r[0]) for r in rows], dtype=np.int64)
        vals = np.array([[float(r[1]), float(r[2])] for r in rows], dtype=np.float64).reshape(-1, 2)
    except (ValueError, IndexError, UnicodeDecodeError) as e:
        raise PanovoccError(f"not a coverage table ({e})", path) from None
    return {"frame": frames, "panoramic": vals[:, 0], "perspective": vals[:, 1]}
