"""Issue 24's "a vocabulary that does not cover every surface", on the feature route: ``panovocc relabel MAP NEW.npz
--vocab couch,bed`` on the no-vocabulary feature maps of scripts/feature_relabel.py (``WORKDIR/featK``, homes of 3
rooms), counted and scored against the ground truth.

For each seed K and each setting, ``run_relabel`` (what ``panovocc relabel`` runs) writes
``WORKDIR/cover{K}_{tag}.npz``; every occupied voxel of it is looked up in the ground-truth grid ``WORKDIR/gK.npz`` at its centre. Per word: the
voxels labelled with it, precision (share of them whose ground-truth class is the word's class: couch -> sofa,
bed -> bed) and recall (share of the occupied voxels of that class that keep the word); and the voxels left
occupied-unclassed (254).

Usage: ``python scripts/feature_unclassed.py WORKDIR --seeds 2 3 4 [--background scannet200 none]
[--fold 0.7] [--margin 0.0]`` (every combination of the listed values; prints a markdown table and the
equivalent ``panovocc relabel`` command of each row).
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np

WORDS = {"couch": "sofa", "bed": "bed"}


def occupied_gt_labels(pred, gt):
    """(labels of the occupied voxels of grid ``pred``, ground-truth class ids at their centres; -1 outside)."""
    ijk = np.argwhere((pred.labels >= 1) & (pred.labels <= 254))
    centres = np.asarray(pred.origin) + ijk * pred.voxel_size
    idx = np.rint((centres - np.asarray(gt.origin)) / gt.voxel_size).astype(np.int64)
    inside = np.all((idx >= 0) & (idx < np.array(gt.labels.shape)), axis=1)
    g = np.full(len(idx), -1, np.int64)
    g[inside] = gt.labels[tuple(idx[inside].T)]
    return pred.labels[tuple(ijk.T)].astype(np.int64), g


def main() -> None:
    from panovocc_cli.cli.query_cmds import RelabelConfig, run_relabel
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.semantics.query import minilm_encoder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4])
    ap.add_argument("--vocab", default=",".join(WORDS))
    ap.add_argument("--background", nargs="+", default=["scannet200"])
    ap.add_argument("--fold", type=float, nargs="+", default=[None])
    ap.add_argument("--margin", type=float, nargs="+", default=[None])
    a = ap.parse_args()
    enc = minilm_encoder()
    words = a.vocab.split(",")
    print("| seed | background | fold | margin | occupied | " + " | ".join(
        f"{w}: voxels / precision / recall ({WORDS.get(w, w)})" for w in words) + " | unclassed (254) |")
    print("|---" * (6 + len(words)) + "|")
    commands = []
    totals = {}
    for bg, fold, margin in itertools.product(a.background, a.fold, a.margin):
        for k in a.seeds:
            tag = f"{bg}_{fold}_{margin}".replace(",", "+")
            out = a.work / f"cover{k}_{tag}.npz"
            kw = {"background": bg}
            if fold is not None:
                kw["fold_similarity"] = fold
            if margin is not None:
                kw["feature_margin"] = margin
            cfg = RelabelConfig(map_dir=a.work / f"feat{k}", out_npz=out, vocab=a.vocab, overwrite=True, **kw)
            res = run_relabel(cfg, encode=enc)
            extra = "".join(f" --{n.replace('_', '-')} {v}" for n, v in kw.items())
            commands.append(f"panovocc relabel {cfg.map_dir} {out} --vocab {a.vocab}{extra} --overwrite")
            pred, gt = read_grid(out), read_grid(a.work / f"g{k}.npz")
            lab, g = occupied_gt_labels(pred, gt)
            names = list(pred.class_names)
            gnames = list(gt.class_names)
            cells = []
            t = totals.setdefault((bg, fold, margin), {"occ": 0, "unc": 0})
            t["occ"] += len(lab)
            t["unc"] += int((lab == 254).sum())
            for w in words:
                mine = lab == names.index(w)
                truth = g == (gnames.index(WORDS.get(w, w)) if WORDS.get(w, w) in gnames else -2)
                tp = int((mine & truth).sum())
                for key, v in (("n", int(mine.sum())), ("tp", tp), ("pos", int(truth.sum()))):
                    t[(w, key)] = t.get((w, key), 0) + v
                prec = tp / max(1, int(mine.sum()))
                rec = tp / max(1, int(truth.sum()))
                cells.append(f"{int(mine.sum()):,} / {100 * prec:.1f} / {100 * rec:.1f}")
            print(f"| {k} | {bg} | {fold} | {margin} | {len(lab):,} | " + " | ".join(cells) +
                  f" | {int((lab == 254).sum()):,} |", flush=True)
            assert res["unclassed"] == int((lab == 254).sum()), (res["unclassed"], int((lab == 254).sum()))
    for (bg, fold, margin), t in totals.items():
        cells = [f"{t[(w, 'n')]:,} / {100 * t[(w, 'tp')] / max(1, t[(w, 'n')]):.1f} / "
                 f"{100 * t[(w, 'tp')] / max(1, t[(w, 'pos')]):.1f}" for w in words]
        print(f"| all {a.seeds} | {bg} | {fold} | {margin} | {t['occ']:,} | " + " | ".join(cells) +
              f" | {t['unc']:,} |")
    print("\ncommands:\n" + "\n".join(commands))


if __name__ == "__main__":
    main()
