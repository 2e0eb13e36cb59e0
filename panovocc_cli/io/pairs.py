"""The pairs CSV of ``panovocc eval --pairs``: one ``prediction,ground_truth`` pair of grid paths a line.

Format: two columns (prediction ``.npz``, ground truth ``.npz``); an optional header ``pred,gt`` (or
``prediction,ground_truth``) on the first line; blank lines and lines starting with ``#`` are skipped;
relative paths are resolved against the CSV's folder. UTF-8 text.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Sequence

from ..errors import PanovoccError
from .atomic import write_text

EXPECTED = "a CSV of 'prediction.npz,ground_truth.npz' lines"


def read_pairs_csv(path: str | Path) -> list[tuple[Path, Path]]:
    """Read the pairs a CSV lists.

    Returns
    -------
    pairs : list of (prediction path, ground-truth path), relative entries resolved from the CSV's folder

    Raises
    ------
    PanovoccError naming the file: missing, a folder, not UTF-8 text (a binary file), a line with fewer
    than two columns, or no pair at all.
    """
    path = Path(path)
    if path.is_dir():
        raise PanovoccError(f"is a folder (expected {EXPECTED})", path)
    if not path.is_file():
        raise PanovoccError(f"pairs CSV not found (expected {EXPECTED})", path)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise PanovoccError(f"not UTF-8 text at byte {e.start} (expected {EXPECTED})", path) from None
    if "\x00" in text:
        raise PanovoccError(f"contains NUL bytes: a binary file? (expected {EXPECTED})", path)
    pairs: list[tuple[Path, Path]] = []
    try:
        for n, row in enumerate(csv.reader(text.splitlines()), start=1):
            row = [c.strip() for c in row]
            if not row or not any(row) or row[0].startswith("#"):
                continue
            if len(row) < 2 or not row[0] or not row[1]:
                raise PanovoccError(f"line {n}: expected two columns (prediction, ground truth)", path)
            if n == 1 and row[0].lower() in ("pred", "prediction") and row[1].lower() in ("gt", "ground_truth"):
                continue
            a, b = Path(row[0]), Path(row[1])
            pairs.append((a if a.is_absolute() else path.parent / a, b if b.is_absolute() else path.parent / b))
    except csv.Error as e:
        raise PanovoccError(f"not a valid CSV ({e}; expected {EXPECTED})", path) from None
    if not pairs:
        raise PanovoccError(f"no pairs listed (expected {EXPECTED})", path)
    return pairs


def write_pairs_csv(path: str | Path, pairs: Sequence[tuple[str | Path, str | Path]]) -> None:
    """Atomically write pairs with the header ``pred,gt`` (paths as given)."""
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["pred", "gt"])
    w.writerows([[str(a), str(b)] for a, b in pairs])
    write_text(path, buf.getvalue())
