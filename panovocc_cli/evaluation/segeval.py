"""``panovocc segeval``: a segmenter's own per-frame 2D mIoU on a labelled sequence (the loop; the
per-frame scores are :mod:`panovocc_cli.semantics.metrics2d`'s). Its config is light, for ``--help``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import DEFAULT_SEED, option, validate_config
from ..errors import PanovoccError


@dataclass
class SegevalConfig:
    """``panovocc segeval``: the segmenter's own per-frame 2D mIoU on a labelled sequence."""

    seq: str = option(cli_type=Path, parse=str, argument=True, metavar="SEQ",
                      help="Sequence folder with ground-truth labels (semantic/).")
    segmenter: str = option("simulated", help="Segmenter to score: simulated | precomputed:DIR.")
    vocab: object = option(None, cli_type=str, help="Vocabulary (as for map); default eval8,open4.")
    noise: float = option(1.0, min=0, help="Simulated segmenter noise level (dimensionless; 0 = exact).")
    seed: int = option(DEFAULT_SEED, min=0, help="Seed of the simulated segmenter's noise.")
    classes: str = option("eval8", help="Scored class set: eval8 | open4 | eval12 | comma list (a,b,c).")
    every: int = option(1, min=1, help="Score every K-th frame (frames 0, K, 2K, ...).")


def run_segeval(cfg: SegevalConfig, progress: bool = True):
    """Pooled 2D mIoU of the segmenter over frames ``0, every, 2 every, ...`` of ``cfg.seq``.

    Returns
    -------
    (Miou2D, frames) : the pooled result (.miou, .iou, .accuracy) and the scored frame indices

    Raises
    ------
    PanovoccError
        Bad ``every``, no labels, a bad vocabulary or class list, or a class list none of whose classes
        occur in the sequence's class names (a mean over no class).
    """
    from ..classes import canonical_name, parse_class_set, parse_vocab
    from ..io.sequence import Sequence
    from ..semantics.metrics2d import empty_scores, frame_scores
    from ..semantics.registry import SEGMENTER_AUTO, SIMULATED, build_segmenter
    from ..semantics.simulated import sequence_label_source

    cfg = validate_config(cfg)  # noise, seed, every: the ranges declared on SegevalConfig
    seq = Sequence(cfg.seq)
    if not seq.has_labels:
        raise PanovoccError("segeval needs ground-truth labels (semantic/)", seq.root)
    names = list(seq.meta.class_names)
    vocab = parse_vocab(cfg.vocab, names, what="vocabulary (--vocab)")
    classes = parse_class_set(cfg.classes, names)
    known = {canonical_name(n) for n in names[1:]}
    if not any(c in known for c in classes):
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the sequence's labels "
                            f"(its classes: {', '.join(sorted(known))})", seq.root / "meta.json")
    spec = cfg.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        spec = SIMULATED
    seg = build_segmenter(spec, seed=int(cfg.seed), noise=float(cfg.noise), label_source=sequence_label_source(seq))
    frames = list(range(0, len(seq), cfg.every))
    total = empty_scores(classes)
    it = frames
    if progress:
        from tqdm import tqdm

        it = tqdm(frames, desc="2D mIoU", unit="frame")
    for i in it:
        logits = seg.logits(seq.rgb(i), vocab, frame_id=i)
        total.add(frame_scores(np.argmax(logits, axis=-1), vocab, seq.labels(i), names, classes))
    if not total.present.any():
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the labels of the scored frames",
                            seq.root)
    return total, frames
