"""A hand-written similarity table between common indoor class names.

It says how readily an open-vocabulary segmenter mistakes one class for another, or, for a class that
is not in the user's vocabulary, which vocabulary words it would call it instead (a pillow is called
``bed`` or ``sofa``, a rug ``floor``, blinds ``window`` or ``curtain``). Values lie in [0, 1]; 1 means
the same class. The simulated segmenter (:mod:`.simulated`) builds its clean logits and its confusion
structure from it.

Names are canonical (:func:`classes.canonical_name`): Replica's ``lamp`` is ``lighting``, ``tv-screen``
is ``tv``. Pairs are symmetric. Names missing from the table fall back to shared hyphen-separated
tokens (``wall-cabinet`` ~ ``cabinet``: :data:`TOKEN_SIMILARITY`), and otherwise to 0.
"""

from __future__ import annotations

from functools import lru_cache

from ..classes import canonical_name

TOKEN_SIMILARITY = 0.4

_PAIRS: tuple[tuple[str, str, float], ...] = (
    # structure
    ("wall", "door", 0.45), ("wall", "window", 0.3), ("wall", "ceiling", 0.3), ("wall", "curtain", 0.25),
    ("wall", "floor", 0.1), ("wall", "tv", 0.15), ("wall", "lighting", 0.1), ("wall", "picture", 0.5),
    ("wall", "panel", 0.6), ("wall", "vent", 0.55), ("wall", "switch", 0.65), ("wall", "wall-plug", 0.65),
    ("wall", "pillar", 0.7), ("wall", "beam", 0.4), ("wall", "logo", 0.4), ("wall", "clock", 0.4),
    ("wall", "pipe", 0.4), ("wall", "handrail", 0.3), ("wall", "shower-stall", 0.3), ("wall", "shelf", 0.25),
    ("wall", "stair", 0.2), ("wall", "faucet", 0.15), ("wall", "cabinet", 0.15), ("wall", "wardrobe", 0.2),
    ("ceiling", "lighting", 0.5), ("ceiling", "beam", 0.6), ("ceiling", "vent", 0.4), ("ceiling", "pipe", 0.3),
    ("ceiling", "floor", 0.05),
    ("floor", "rug", 0.8), ("floor", "mat", 0.7), ("floor", "stair", 0.5), ("floor", "table", 0.1),
    ("floor", "shoe", 0.4), ("floor", "bed", 0.05),
    ("window", "curtain", 0.55), ("window", "blinds", 0.75), ("window", "door", 0.3), ("window", "tv", 0.2),
    ("window", "picture", 0.3), ("window", "shower-stall", 0.3), ("window", "lighting", 0.15),
    ("window", "indoor-plant", 0.15), ("window", "plant", 0.15),
    ("curtain", "blinds", 0.7), ("curtain", "cloth", 0.4), ("curtain", "towel", 0.35),
    ("curtain", "clothing", 0.25), ("curtain", "door", 0.2),
    ("door", "wardrobe", 0.45), ("door", "cabinet", 0.2), ("door", "refrigerator", 0.4),
    ("door", "shower-stall", 0.4), ("door", "major-appliance", 0.2),
    # seating and beds
    ("chair", "sofa", 0.55), ("chair", "stool", 0.8), ("chair", "bench", 0.6), ("chair", "table", 0.25),
    ("chair", "bed", 0.15), ("chair", "beanbag", 0.6), ("chair", "cushion", 0.35), ("chair", "toilet", 0.3),
    ("chair", "bag", 0.2), ("chair", "backpack", 0.2), ("chair", "basket", 0.2), ("chair", "bin", 0.15),
    ("chair", "exercise-ball", 0.2), ("chair", "sculpture", 0.2), ("chair", "bike", 0.2),
    ("chair", "indoor-plant", 0.15), ("chair", "plant", 0.15),
    ("sofa", "bed", 0.45), ("sofa", "cushion", 0.7), ("sofa", "pillow", 0.6), ("sofa", "beanbag", 0.55),
    ("sofa", "blanket", 0.45), ("sofa", "bench", 0.4), ("sofa", "bag", 0.25), ("sofa", "handbag", 0.25),
    ("sofa", "backpack", 0.25), ("sofa", "clothing", 0.3), ("sofa", "set-of-clothing", 0.3),
    ("sofa", "remote-control", 0.1),
    ("bed", "pillow", 0.75), ("bed", "comforter", 0.85), ("bed", "blanket", 0.7), ("bed", "cushion", 0.4),
    ("bed", "clothing", 0.3), ("bed", "set-of-clothing", 0.3), ("bed", "bathtub", 0.2), ("bed", "mat", 0.15),
    # tables and storage
    ("table", "cabinet", 0.5), ("table", "desk", 0.85), ("table", "nightstand", 0.6), ("table", "countertop", 0.7),
    ("table", "shelf", 0.35), ("table", "tv-stand", 0.5), ("table", "table-runner", 0.7), ("table", "bench", 0.3),
    ("table", "stool", 0.3), ("table", "plant-stand", 0.5), ("table", "box", 0.3), ("table", "bin", 0.2),
    ("table", "basket", 0.2), ("table", "book", 0.3), ("table", "sink", 0.3), ("table", "cooktop", 0.4),
    ("table", "desk-organizer", 0.4), ("table", "vase", 0.25), ("table", "bottle", 0.35), ("table", "cup", 0.35),
    ("table", "bowl", 0.35), ("table", "plate", 0.35), ("table", "pot", 0.3), ("table", "pan", 0.3),
    ("table", "kitchen-utensil", 0.3), ("table", "utensil-holder", 0.35), ("table", "knife-block", 0.35),
    ("table", "chopping-board", 0.4), ("table", "laptop", 0.3), ("table", "tablet", 0.3),
    ("table", "computer-keyboard", 0.35), ("table", "mouse", 0.35), ("table", "phone", 0.35),
    ("table", "remote-control", 0.35), ("table", "camera", 0.3), ("table", "candle", 0.3),
    ("table", "tissue-paper", 0.3), ("table", "paper-towel", 0.25), ("table", "small-appliance", 0.2),
    ("table", "microwave", 0.2), ("table", "indoor-plant", 0.2), ("table", "plant", 0.2),
    ("table", "sculpture", 0.2), ("table", "bathtub", 0.1),
    ("cabinet", "base-cabinet", 0.9), ("cabinet", "wall-cabinet", 0.9), ("cabinet", "wardrobe", 0.7),
    ("cabinet", "shelf", 0.55), ("cabinet", "nightstand", 0.6), ("cabinet", "tv-stand", 0.6),
    ("cabinet", "refrigerator", 0.4), ("cabinet", "major-appliance", 0.4), ("cabinet", "small-appliance", 0.3),
    ("cabinet", "microwave", 0.3), ("cabinet", "countertop", 0.5), ("cabinet", "box", 0.4), ("cabinet", "bin", 0.3),
    ("cabinet", "sink", 0.4), ("cabinet", "rack", 0.3), ("cabinet", "desk", 0.4),
    ("shelf", "book", 0.5), ("shelf", "rack", 0.5),
    # screens and lights
    ("tv", "monitor", 0.85), ("tv", "picture", 0.35), ("tv", "laptop", 0.4), ("tv", "tablet", 0.35),
    ("tv", "desktop-computer", 0.5), ("tv", "microwave", 0.2), ("tv", "small-appliance", 0.2),
    ("tv", "tv-stand", 0.25),
    ("lighting", "candle", 0.3), ("lighting", "lamp", 1.0),
    # bathroom / kitchen
    ("sink", "countertop", 0.6), ("sink", "faucet", 0.5), ("sink", "toilet", 0.4), ("sink", "bathtub", 0.4),
    ("sink", "toothbrush", 0.3), ("sink", "hair-dryer", 0.2), ("countertop", "cooktop", 0.6),
    ("towel", "cloth", 0.6), ("blanket", "comforter", 0.8), ("pillow", "cushion", 0.85),
    ("indoor-plant", "plant", 1.0), ("indoor-plant", "vase", 0.4), ("indoor-plant", "plant-stand", 0.5),
    ("stair", "handrail", 0.5), ("rug", "mat", 0.8), ("picture", "logo", 0.3),
)


def _build() -> dict[str, dict[str, float]]:
    table: dict[str, dict[str, float]] = {}
    for a, b, s in _PAIRS:
        a, b = canonical_name(a), canonical_name(b)
        if a == b:
            continue
        table.setdefault(a, {})[b] = max(s, table.get(a, {}).get(b, 0.0))
        table.setdefault(b, {})[a] = max(s, table.get(b, {}).get(a, 0.0))
    return table


SIMILARITY: dict[str, dict[str, float]] = _build()
"""``SIMILARITY[a][b]``: how similar canonical class ``a`` is to ``b`` (symmetric, in (0, 1])."""


def is_known(name: str) -> bool:
    """Whether the table knows ``name`` (after :func:`classes.canonical_name`)."""
    return canonical_name(name) in SIMILARITY


@lru_cache(maxsize=65536)
def similarity(a: str, b: str) -> float:
    """Similarity in [0, 1] of two class names (1 for the same canonical name).

    A pair in the table gives its value; otherwise names sharing a hyphen-separated token
    (``wall-cabinet``, ``cabinet``) give :data:`TOKEN_SIMILARITY`; otherwise 0.
    """
    a, b = canonical_name(a), canonical_name(b)
    if a == b:
        return 1.0
    s = SIMILARITY.get(a, {}).get(b)
    if s is not None:
        return s
    if set(a.replace(" ", "-").split("-")) & set(b.replace(" ", "-").split("-")):
        return TOKEN_SIMILARITY
    return 0.0
