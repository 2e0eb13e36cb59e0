"""Class names: canonical benchmark sets and the mapping of Replica's names onto them.

Ids are positions in a ``class_names`` list carried next to the data, never a global table.
Id 0 is ``unlabeled`` in images and ``empty`` in grids (CONVENTIONS.md).
"""

from __future__ import annotations

import re
from typing import Iterable, Sequence

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


def check_text(text: str, what: str) -> str:
    """``text`` if it is valid UTF-8 text, else a one-line :class:`PanovoccError` naming ``what``.

    A command-line word that is not UTF-8 (a Latin-1 byte) reaches Python as a string with lone surrogates
    (``surrogateescape``); text models, tokenizers and JSON writers fail on it with a traceback. Every
    vocabulary and query text is checked here first (``map --vocab``, ``eval --classes``, ``query``,
    ``relabel --vocab``).
    """
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        try:  # the bytes as given (a Latin-1 e-acute shows as \xe9)
            raw = text.encode("utf-8", "surrogateescape")
        except UnicodeEncodeError:
            raw = text.encode("utf-8", "backslashreplace")
        raise PanovoccError(f"{what} '{raw.decode('utf-8', 'backslashreplace')}' is not valid UTF-8 text") from None
    return text


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


# Grid labels 1..253 index a class list whose entry 0 is "empty" (CONVENTIONS.md).
MAX_VOCAB = 253

# Named class sets of ``--vocab`` and ``--classes``; ``all`` (the classes present in the data at hand:
# the sequence's for ``map``/``segeval``, the ground truth's for ``eval``) is resolved by the caller.
NAMED_SETS: dict[str, tuple[str, ...]] = {
    "eval8": EVAL8,
    "open4": OPEN4,
    "eval12": DEFAULT_VOCAB,
    "default": DEFAULT_VOCAB,
}
ALL = "all"
_SET_LIKE = re.compile(r"^(eval|open)\d+$")


def parse_vocab(spec: str | Sequence[str] | None = None, available: Sequence[str] | None = None,
                what: str = "vocabulary") -> list[str]:
    """The one parser of class lists: ``map --vocab``, ``segeval --vocab/--classes``, ``eval --classes``.

    Parameters
    ----------
    spec : str, sequence of str or None
        ``None`` or ``"default"`` gives eval8 + open4 (:data:`DEFAULT_VOCAB`). A string is a comma- or
        ``+``-separated list whose items are class names or the named sets ``eval8``, ``open4``,
        ``eval12`` (= ``default``) and ``all`` (e.g. ``"eval8+open4"``, ``"eval8,pillow,rug"``).
    available : sequence of str or None
        The classes ``all`` stands for (the data's class names; ``empty``/``unlabeled`` are dropped).
        None: ``all`` is an error.
    what : str, the option's name in error messages

    Returns
    -------
    names : list of str
        Canonical names (:func:`canonical_name`: ``lamp`` -> ``lighting``), in the order given,
        duplicates removed (first occurrence kept).

    Raises
    ------
    PanovoccError
        If the list is empty, names the reserved ``empty``/``unlabeled`` classes, names an unknown set
        (``eval99``, ``open7``: set-like names are never taken as class names), uses ``all`` without
        data to resolve it, or has more than 253 classes (the grid format's limit).
    """
    if spec is None:
        items: Iterable[str] = DEFAULT_VOCAB
        shown = "default"
    elif isinstance(spec, str):
        shown = check_text(spec, what)
        items = [t for part in spec.split(",") for t in part.split("+")]
    else:
        shown = ",".join(map(str, spec))
        items = spec
    out: list[str] = []
    seen: set[str] = set()
    for raw in items:
        if not isinstance(raw, str):
            raise PanovoccError(f"{what} {shown!r}: class names must be strings, got {raw!r}")
        check_text(raw, what)
        token = raw.strip().lower()
        if not token:
            continue
        if token == ALL:
            if available is None:
                raise PanovoccError(f"{what} {shown!r}: 'all' needs data to take the classes from")
            names: Iterable[str] = [n for n in available if canonical_name(n) not in (EMPTY, UNLABELED)]
        elif token in NAMED_SETS:
            names = NAMED_SETS[token]
        elif _SET_LIKE.match(token):
            raise PanovoccError(f"{what} {shown!r}: unknown class set {token!r}; the sets are "
                                f"{', '.join(list(NAMED_SETS) + [ALL])}")
        else:
            names = (token,)
        for n in names:
            c = canonical_name(n)
            if c in (EMPTY, UNLABELED):
                raise PanovoccError(f"{what} {shown!r}: {c!r} is reserved (id 0 of images and grids)")
            if c not in seen:
                seen.add(c)
                out.append(c)
    if not out:
        raise PanovoccError(f"empty {what} {shown!r}: expected class names or the sets "
                            f"{', '.join(list(NAMED_SETS) + [ALL])}, e.g. 'eval8,curtain'")
    if len(out) > MAX_VOCAB:
        raise PanovoccError(f"{what} has {len(out)} classes, at most {MAX_VOCAB} fit in a grid")
    return out


def parse_class_set(spec: str, available: Sequence[str] | None = None) -> list[str]:
    """Classes to score (``eval --classes``, ``segeval --classes``): :func:`parse_vocab` with ``all`` =
    ``available`` (the ground truth's classes)."""
    return parse_vocab(spec, available, what="class list")
