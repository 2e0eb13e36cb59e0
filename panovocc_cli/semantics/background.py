"""Background words of the feature route's relabelling: what a surface may be when it is none of the words asked.

``panovocc relabel MAP NEW.npz --vocab couch,bed`` by features (:func:`.features.feature_distribution`)
classifies each voxel over the asked words *and* these words; a background word that is a synonym of an
asked word (text cosine at least the fold similarity) counts for that word, the others for
occupied-unclassed (254). So a wall voxel, which is more like ``bed`` than like ``couch`` but far more like
``wall``, is left unclassed, and a sofa voxel is still ``couch``.

The default list is fixed and independent of any scene of this toolkit: the 200 class names of the
ScanNet200 benchmark (``CLASS_LABELS_200`` of ScanNet's BenchmarkScripts, in its order), the standard
indoor open-vocabulary label set, plus LERF's canonical negative phrases (``object`` is already among
ScanNet200's; "things", "stuff", "texture").
"""

from __future__ import annotations

SCANNET200 = (
    "wall", "chair", "floor", "table", "door", "couch", "cabinet", "shelf", "desk", "office chair", "bed", "pillow",
    "sink", "picture", "window", "toilet", "bookshelf", "monitor", "curtain", "book", "armchair", "coffee table", "box",
    "refrigerator", "lamp", "kitchen cabinet", "towel", "clothes", "tv", "nightstand", "counter", "dresser", "stool",
    "cushion", "plant", "ceiling", "bathtub", "end table", "dining table", "keyboard", "bag", "backpack",
    "toilet paper", "printer", "tv stand", "whiteboard", "blanket", "shower curtain", "trash can", "closet", "stairs",
    "microwave", "stove", "shoe", "computer tower", "bottle", "bin", "ottoman", "bench", "board", "washing machine",
    "mirror", "copier", "basket", "sofa chair", "file cabinet", "fan", "laptop", "shower", "paper", "person",
    "paper towel dispenser", "oven", "blinds", "rack", "plate", "blackboard", "piano", "suitcase", "rail", "radiator",
    "recycling bin", "container", "wardrobe", "soap dispenser", "telephone", "bucket", "clock", "stand", "light",
    "laundry basket", "pipe", "clothes dryer", "guitar", "toilet paper holder", "seat", "speaker", "column", "bicycle",
    "ladder", "bathroom stall", "shower wall", "cup", "jacket", "storage bin", "coffee maker", "dishwasher",
    "paper towel roll", "machine", "mat", "windowsill", "bar", "toaster", "bulletin board", "ironing board",
    "fireplace", "soap dish", "kitchen counter", "doorframe", "toilet paper dispenser", "mini fridge",
    "fire extinguisher", "ball", "hat", "shower curtain rod", "water cooler", "paper cutter", "tray", "shower door",
    "pillar", "ledge", "toaster oven", "mouse", "toilet seat cover dispenser", "furniture", "cart", "storage container",
    "scale", "tissue box", "light switch", "crate", "power outlet", "decoration", "sign", "projector", "closet door",
    "vacuum cleaner", "candle", "plunger", "stuffed animal", "headphones", "dish rack", "broom", "guitar case",
    "range hood", "dustpan", "hair dryer", "water bottle", "handicap bar", "purse", "vent", "shower floor",
    "water pitcher", "mailbox", "bowl", "paper bag", "alarm clock", "music stand", "projector screen", "divider",
    "laundry detergent", "bathroom counter", "object", "bathroom vanity", "closet wall", "laundry hamper",
    "bathroom stall door", "ceiling light", "trash bin", "dumbbell", "stair rail", "tube", "bathroom cabinet",
    "cd case", "closet rod", "coffee kettle", "structure", "shower head", "keyboard piano", "case of water bottles",
    "coat rack", "storage organizer", "folded chair", "fire alarm", "power strip", "calendar", "poster", "potted plant",
    "luggage", "mattress")
#: LERF's canonical phrases (Kerr et al. 2023) not already among ScanNet200's names.
LERF_NEGATIVES = ("things", "stuff", "texture")
DEFAULT_BACKGROUND = SCANNET200 + LERF_NEGATIVES
#: ``--background`` names: the default list, or none (the asked words alone, as before background words).
BACKGROUND_SETS = {"scannet200": DEFAULT_BACKGROUND, "none": ()}


def background_words(spec: str) -> tuple[str, ...]:
    """``--background SPEC``: ``scannet200`` (the default list), ``none``, or comma-separated words (duplicates
    dropped, order kept)."""
    from ..classes import check_text

    s = check_text(spec or "", "the background words (--background)").strip()
    if s.lower() in BACKGROUND_SETS:
        return BACKGROUND_SETS[s.lower()]
    return tuple(dict.fromkeys(w.strip() for w in s.split(",") if w.strip()))
