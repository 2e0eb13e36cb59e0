"""Class names: canonical benchmark sets and the mapping of Replica's names onto them.

Ids are positions in a ``class_names`` list carried next to the data, never a global table.
Id 0 is ``unlabeled`` in images and ``empty`` in grids (CONVENTIONS.md).
"""

from __future__ import annotations

from typing import Sequence

from .errors import PanovoccError

UNLABELED = "unlabeled"
EMPTY = "empty"

EVAL8: tuple[str, ...] = ("ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table")
OPEN4: tuple[str, ...] = ("curtain", "door", "tv", "lighting")
DEFAULT_VOCAB: tuple[str, ...] = EVAL8 + OPEN4

# Replica -> canonical; every other Replica class keeps its own name.
REPLICA_TO_CANONICAL: dict[str, str] = {"tv-screen": "tv", "lamp": "lighting"}

# Paper colours (RGB 0..255) for the 12 benchmark classes; other classes get a fixed hashed colour.
PAPER_COLORS: dict[str, tuple[int, int, int]] = {
    "ceiling": (0xE6, 0x2F, 0x35),
    "floor": (0x25, 0xA5, 0x34),
    "wall": (0x9B, 0xD6, 0xE2),
    "window": (0x73, 0x99, 0xCF),
    "chair": (0xC4, 0xC9, 0x43),
    "bed": (0xFF, 0xB1, 0x68),
    "sofa": (0x8F, 0x6A, 0xB0),
    "table": (0x20, 0x74, 0xB8),
    "curtain": (188, 189, 34),
    "door": (140, 86, 75),
    "tv": (31, 119, 180),
    "lighting": (255, 187, 120),
}


def canonical_name(name: str) -> str:
    """Lower-case, trimmed, with Replica's aliases mapped (``tv-screen`` -> ``tv``, ``lamp`` -> ``lighting``)."""
    n = name.strip().lower()
    return REPLICA_TO_CANONICAL.get(n, n)


def class_color(name: str) -> tuple[int, int, int]:
    """Fixed RGB colour of a class: the paper's for the benchmark classes, a stable hash otherwise."""
    if name in PAPER_COLORS:
        return PAPER_COLORS[name]
    import zlib

    h = zlib.crc32(name.encode("utf-8"))
    return (64 + (h & 0x7F), 64 + ((h >> 8) & 0x7F), 64 + ((h >> 16) & 0x7F))


def parse_class_set(spec: str, available: Sequence[str] | None = None) -> list[str]:
    """Resolve ``eval8`` | ``open4`` | ``all`` | ``a,b,c`` into a list of class names.

    ``all`` needs ``available`` (the names present, without ``empty``/``unlabeled``).
    """
    s = spec.strip().lower()
    if s == "eval8":
        return list(EVAL8)
    if s == "open4":
        return list(OPEN4)
    if s == "eval12":
        return list(DEFAULT_VOCAB)
    if s == "all":
        if available is None:
            raise PanovoccError("class set 'all' needs the classes of the ground truth")
        return [c for c in available if c not in (EMPTY, UNLABELED)]
    names = [canonical_name(c) for c in s.split(",") if c.strip()]
    if not names:
        raise PanovoccError(f"empty class list {spec!r}: expected eval8, open4, all or a comma-separated list")
    return names
