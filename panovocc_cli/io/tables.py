"""Score tables on disk: CSV, GitHub Markdown and LaTeX (booktabs) text from a header and string rows.

The rows come from :mod:`panovocc_cli.evaluation.tables` (a list of Results -> formatted cells); this
module only knows the three text formats and writes them atomically.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Sequence

from .atomic import write_text


def csv_text(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """CSV text (``\\n`` line ends) of a header and rows."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(list(header))
    w.writerows([list(r) for r in rows])
    return buf.getvalue()


def markdown_text(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """GitHub Markdown table text: the first two columns left-aligned, the rest right-aligned."""
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join(["---"] * min(2, len(header)) + ["---:"] * max(0, len(header) - 2)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _tex_escape(s: str) -> str:
    return s.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("&", r"\&").replace("%", r"\%")


def latex_text(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A LaTeX ``tabular`` (booktabs): first two columns ``l``, the rest ``r``."""
    cols = "l" * min(2, len(header)) + "r" * max(0, len(header) - 2)
    out = [r"\begin{tabular}{" + cols + "}", r"\toprule",
           " & ".join(_tex_escape(h) for h in header) + r" \\", r"\midrule"]
    out += [" & ".join(_tex_escape(c) for c in r) + r" \\" for r in rows]
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def write_tables(header: Sequence[str], rows: Sequence[Sequence[str]], out_dir: str | Path,
                 stem: str = "scores") -> list[Path]:
    """Write ``<stem>.csv``, ``<stem>.md`` and ``<stem>.tex`` into ``out_dir``, each atomically.

    Returns
    -------
    paths : the three files written, in that order
    """
    out = Path(out_dir)
    paths = [out / f"{stem}.csv", out / f"{stem}.md", out / f"{stem}.tex"]
    for p, text in zip(paths, (csv_text(header, rows), markdown_text(header, rows), latex_text(header, rows))):
        write_text(p, text)
    return paths


def write_csv(path: str | Path, header: Sequence[str], rows: Sequence[Sequence[object]]) -> None:
    """Atomically write one CSV file."""
    write_text(path, csv_text(header, rows))
