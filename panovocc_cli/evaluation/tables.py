"""Score tables from a list of :class:`~panovocc_cli.evaluation.metrics.Result`: header and formatted rows.

One row per result (a method, a scene, a mask), columns ``IoU``, ``mIoU`` (FreeOcc's rule, the
headline), ``mIoU_present`` (mean over the classes present in the ground truth) and one per class, all
percent with two decimals like the paper; classes absent from a row's ground truth show ``-`` (they
count 0 in ``mIoU``). The text formats (CSV, Markdown, LaTeX) and the files are
:mod:`panovocc_cli.io.tables`. Pure: no files, no printing.
"""

from __future__ import annotations

import math
from typing import Sequence

from .metrics import Result

NA = "-"


def _fmt(x: float) -> str:
    return NA if x is None or math.isnan(x) else f"{x:.2f}"


def table_rows(results: Sequence[Result], names: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """Header and formatted rows (strings) of a score table.

    Parameters
    ----------
    results : Results, one per row
    names : row labels, one per result

    Returns
    -------
    header : ["name", "mask", "IoU", "mIoU", "mIoU_present", class...]
    rows : list of string rows; per-class cells are ``-`` when the class is absent from that ground truth
    """
    classes: list[str] = []
    for r in results:
        classes += [c for c in r.classes if c not in classes]
    header = ["name", "mask", "IoU", "mIoU", "mIoU_present"] + classes
    rows = []
    for r, n in zip(results, names):
        present = set(r.present)
        cells = [str(n), r.mask, _fmt(r.iou), _fmt(r.miou), _fmt(r.miou_present)]
        cells += [_fmt(r.class_iou(c)) if c in present else NA for c in classes]
        rows.append(cells)
    return header, rows


def counts_rows(results: Sequence[Result], names: Sequence[str]) -> tuple[list[str], list[list[object]]]:
    """Long-form raw counts behind each row: name, mask, class, tp, fp, fn, tn (class ``occupancy`` first)."""
    header = ["name", "mask", "class", "tp", "fp", "fn", "tn"]
    rows: list[list[object]] = []
    for r, n in zip(results, names):
        c = r.counts
        rows.append([n, r.mask, "occupancy", c.tp, c.fp, c.fn, c.tn])
        for cls, v in c.classes.items():
            rows.append([n, r.mask, cls, int(v[0]), int(v[1]), int(v[2]), ""])
    return header, rows
