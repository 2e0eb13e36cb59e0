"""Held-out words on a feature map (issue 24): average precision of the voxels a query ranks.

For each (text, ground-truth class) pair below, none of whose texts the map was ever given (the map is
built with the one placeholder word ``object`` and ``--features``: scripts/feature_relabel.py's ``featK``),
``MapQuery(map).answer(text)`` scores every occupied voxel by the cosine of its fused feature with the text
(:mod:`panovocc_cli.semantics.features`); the voxels are ranked by that score and the ranking's average
precision is taken against the occupied voxels whose ground-truth label (the ``gK.npz`` grid at the voxel's
centre) is the class. ``prevalence`` (the class's share of the occupied voxels) is the AP of a random ranking.

Usage: ``python scripts/feature_heldout.py WORKDIR --seeds 0 1 2`` (after scripts/feature_relabel.py).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HELD_OUT = [("couch", "sofa"), ("television", "tv"), ("somewhere to sleep", "bed"), ("a lamp", "lighting"),
            ("carpet", "rug"), ("drapes", "curtain"), ("a houseplant", "plant"), ("bedside table", "nightstand"),
            ("a cupboard", "cabinet"), ("a throw pillow", "cushion"), ("an armchair", "chair"),
            ("a doorway", "door"), ("window pane", "window"), ("the ground", "floor")]


def average_precision(scores: np.ndarray, positive: np.ndarray) -> float:
    """AP of ranking by ``scores`` (descending; ties in index order) against boolean ``positive``."""
    order = np.argsort(-scores, kind="stable")
    hit = positive[order]
    if not hit.any():
        return float("nan")
    prec = np.cumsum(hit) / np.arange(1, len(hit) + 1)
    return float(prec[hit].mean())


def main() -> None:
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.mapquery import MapQuery
    from panovocc_cli.semantics.query import minilm_encoder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    a = ap.parse_args()
    enc = minilm_encoder()
    table = {t: [] for t, _ in HELD_OUT}
    prev = {t: [] for t, _ in HELD_OUT}
    for k in a.seeds:
        q = MapQuery(a.work / f"feat{k}", encoder=lambda: enc, by="features")
        gt = read_grid(a.work / f"g{k}.npz")
        idx = np.rint((q.export.centres() - np.asarray(gt.origin)) / gt.voxel_size).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < np.array(gt.labels.shape)), axis=1)
        lab = np.full(len(idx), -1, np.int64)
        lab[inside] = gt.labels[tuple(idx[inside].T)]
        names = list(gt.class_names)
        for text, cls in HELD_OUT:
            if cls not in names:
                continue
            pos = lab == names.index(cls)
            if not pos.any():
                continue
            s = q.answer(text).scores
            table[text].append(average_precision(s, pos))
            prev[text].append(float(pos.mean()))
    print(f"| text (never given to the map) | class | AP, mean over seeds {a.seeds} | prevalence (random AP) |")
    print("|---|---|---|---|")
    aps = []
    for text, cls in HELD_OUT:
        if table[text]:
            m = float(np.mean(table[text]))
            aps.append(m)
            print(f"| {text} | {cls} | {100 * m:.1f} | {100 * float(np.mean(prev[text])):.1f} |")
    print(f"| mean | | {100 * float(np.mean(aps)):.1f} | |")


if __name__ == "__main__":
    main()
