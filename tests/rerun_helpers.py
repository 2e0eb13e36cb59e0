"""Reading a Rerun recording back with Rerun's own reader (``rerun.chunk.RrdReader``) for the viz tests."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np


def read_rrd(path: str | Path) -> dict[str, list[dict]]:
    """Entity path (without the leading "/") -> its logged rows, each ``{column: value}`` (``frame`` the timeline's
    value or None for static rows), ordered by frame."""
    from rerun.chunk import RrdReader

    out = defaultdict(list)
    for ch in RrdReader(str(path)).stream():
        rb = ch.to_record_batch()
        cols = {n: rb.column(n).to_pylist() for n in rb.schema.names if not n.startswith("rerun.")}
        for r in range(rb.num_rows):
            row = {n: v[r] for n, v in cols.items()}
            row.setdefault("frame", None)
            out[ch.entity_path.lstrip("/")].append(row)
    for rows in out.values():
        rows.sort(key=lambda row: -1 if row["frame"] is None else row["frame"])
    return dict(out)


def boxes(row: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """(centres (n, 3) float32, class ids (n,) or None) of a Boxes3D row."""
    c = np.asarray(row["Boxes3D:centers"], np.float32).reshape(-1, 3)
    ids = row.get("Boxes3D:class_ids")
    return c, None if ids is None else np.asarray(ids, np.int64)
