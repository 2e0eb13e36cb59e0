"""Score tables from a list of :class:`~panovocc_cli.evaluation.metrics.Result`: CSV, Markdown, LaTeX.

One row per result (a method, a scene, a mask), columns ``IoU``, ``mIoU`` and one per class, all
percent with two decimals like the paper; classes absent from a row's ground truth show ``-``.
Used by ``panovocc eval --out`` and by ``make reproduce-tables``.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Sequence

from ..io.atomic import write_text
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
    header : ["name", "mask", "IoU", "mIoU", class...]
    rows : list of string rows; per-class cells are ``-`` when the class is absent from that ground truth
    """
    classes: list[str] = []
    for r in results:
        classes += [c for c in r.classes if c not in classes]
    header = ["name", "mask", "IoU", "mIoU"] + classes
    rows = []
    for r, n in zip(results, names):
        present = set(r.present)
        cells = [str(n), r.mask, _fmt(r.iou), _fmt(r.miou)]
        cells += [_fmt(r.class_iou(c)) if c in present else NA for c in classes]
        rows.append(cells)
    return header, rows


def to_csv(results: Sequence[Result], names: Sequence[str]) -> str:
    """CSV text of the table (percent, 2 decimals)."""
    header, rows = table_rows(results, names)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def to_markdown(results: Sequence[Result], names: Sequence[str]) -> str:
    """GitHub Markdown table text."""
    header, rows = table_rows(results, names)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(header) - 2)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _tex_escape(s: str) -> str:
    return s.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("&", r"\&").replace("%", r"\%")


def to_latex(results: Sequence[Result], names: Sequence[str]) -> str:
    """A LaTeX ``tabular`` (booktabs) of the table."""
    header, rows = table_rows(results, names)
    cols = "ll" + "r" * (len(header) - 2)
    out = [r"\begin{tabular}{" + cols + "}", r"\toprule",
           " & ".join(_tex_escape(h) for h in header) + r" \\", r"\midrule"]
    out += [" & ".join(_tex_escape(c) for c in r) + r" \\" for r in rows]
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def write_tables(results: Sequence[Result], names: Sequence[str], out_dir: str | Path,
                 stem: str = "scores") -> list[Path]:
    """Write ``<stem>.csv``, ``<stem>.md`` and ``<stem>.tex`` into ``out_dir`` (atomically).

    Returns
    -------
    paths : the three files written
    """
    out = Path(out_dir)
    paths = [out / f"{stem}.csv", out / f"{stem}.md", out / f"{stem}.tex"]
    for p, text in zip(paths, (to_csv(results, names), to_markdown(results, names), to_latex(results, names))):
        write_text(p, text)
    return paths


def counts_csv(results: Sequence[Result], names: Sequence[str]) -> str:
    """Long-form CSV of the raw counts behind each row: name, mask, class, tp, fp, fn (class ``occupancy`` too)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["name", "mask", "class", "tp", "fp", "fn", "tn"])
    for r, n in zip(results, names):
        c = r.counts
        w.writerow([n, r.mask, "occupancy", c.tp, c.fp, c.fn, c.tn])
        for cls, v in c.classes.items():
            w.writerow([n, r.mask, cls, int(v[0]), int(v[1]), int(v[2]), ""])
    return buf.getvalue()
