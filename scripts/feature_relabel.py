"""Issue 24's measurement: a map built with no class vocabulary, relabelled afterwards through its feature
memory, against a map built with the full vocabulary from the start (mIoU, FreeOcc protocol).

Per seed K (a home of 3 rooms, 60 frames at 512x256, clean depth, true poses, simulated segmenter at its
default noise, seed 0)::

    panovocc synth W/sK --seed K --rooms 3; panovocc gt W/sK W/gK.npz; panovocc render W/sK W/rK --width 512
    panovocc map W/rK W/vocabK --vocab all --semantic-stride 2 --checkpoint-every 0              # the vocabulary
    panovocc map W/rK W/featK --vocab object --features --semantic-stride 2 --checkpoint-every 0  # one word + features
    panovocc relabel W/featK W/featK/relabel.npz --vocab <the home's 18 classes>  # by features
    panovocc eval PRED W/gK.npz --classes all --json

Both maps measure every second pixel of every second row (``--semantic-stride 2``, the default at 1024x512;
at 512x256 the default is 1): a quarter of the segmenter's pixels, to keep the run short on a shared machine.

Usage: ``python scripts/feature_relabel.py WORKDIR --seeds 0 1 2 [--temperature T --min-sim M --background B
--fold F --margin M --tag _X]``; prints one
row per seed and the mean (markdown), and each command it ran. Steps whose output exists are not redone.
The one-word map (``--vocab object``) has no class knowledge: every pixel of it carries confidence 1 and
its only semantic content is the fused feature. Time per frame of both maps is read from ``--frame-times``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

PANOVOCC = str(Path(sys.executable).with_name("panovocc"))


def run(args, log):
    log.append(" ".join(str(a) for a in ["panovocc"] + list(args)))
    r = subprocess.run([PANOVOCC] + [str(a) for a in args], capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"failed: {log[-1]}\n{r.stderr}")
    return r.stdout


def ms_per_frame(csv_path: Path) -> float:
    """Mean update ms a frame over the frames after the first (``--frame-times``' ``update_ms``)."""
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    vals = [float(r["update_ms"]) for r in rows[1:]]
    return sum(vals) / max(1, len(vals))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--temperature", type=float, default=None, help="relabel --feature-temperature")
    ap.add_argument("--min-sim", type=float, default=None, help="relabel --min-feature-similarity")
    ap.add_argument("--background", default=None, help="relabel --background")
    ap.add_argument("--fold", type=float, default=None, help="relabel --fold-similarity")
    ap.add_argument("--margin", type=float, default=None, help="relabel --feature-margin")
    ap.add_argument("--tag", default="", help="suffix of the relabel output (several settings side by side)")
    a = ap.parse_args()
    w = a.work
    w.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    rows = []
    for k in a.seeds:
        s, g, r = w / f"s{k}", w / f"g{k}.npz", w / f"r{k}"
        if not s.exists():
            run(["synth", s, "--seed", k, "--rooms", 3], log)
        if not g.exists():
            run(["gt", s, g], log)
        if not r.exists():
            run(["render", s, r, "--width", 512], log)
        vocab_map, feat_map = w / f"vocab{k}", w / f"feat{k}"
        if not (vocab_map / "prediction.npz").exists():
            run(["map", r, vocab_map, "--vocab", "all", "--semantic-stride", 2, "--checkpoint-every", 0, "--quiet", "--overwrite",
                 "--frame-times", w / f"vocab{k}.csv"], log)
        if not (feat_map / "prediction.npz").exists():
            run(["map", r, feat_map, "--vocab", "object", "--features", "--semantic-stride", 2, "--checkpoint-every", 0,
                 "--quiet",
                 "--overwrite", "--frame-times", w / f"feat{k}.csv"], log)
        words = json.loads((vocab_map / "config.json").read_text())["semantic"]["vocab"]
        out = w / f"relabel{k}{a.tag}.npz"
        extra = []
        if a.temperature is not None:
            extra += ["--feature-temperature", a.temperature]
        if a.min_sim is not None:
            extra += ["--min-feature-similarity", a.min_sim]
        for flag, v in (("--background", a.background), ("--fold-similarity", a.fold), ("--feature-margin", a.margin)):
            if v is not None:
                extra += [flag, v]
        if not out.exists():
            run(["relabel", feat_map, out, "--vocab", ",".join(words)] + extra, log)
        ev = {}
        for name, pred in (("vocab", vocab_map / "prediction.npz"), ("relabel", out)):
            ev[name] = json.loads(run(["eval", pred, g, "--classes", "all", "--json"], log))
        rows.append((k, ev["vocab"]["miou"], ev["relabel"]["miou"], ev["vocab"]["iou"], ev["relabel"]["iou"],
                     ms_per_frame(w / f"vocab{k}.csv"), ms_per_frame(w / f"feat{k}.csv")))
    print("| seed | mIoU, vocabulary from the start | mIoU, no vocabulary + relabel by features | difference | "
          "IoU (both) | update ms/frame vocab / features |")
    print("|---|---|---|---|---|---|")
    for k, mv, mr, iv, ir, tv, tf in rows:
        print(f"| {k} | {mv:.2f} | {mr:.2f} | {mr - mv:+.2f} | {iv:.2f} / {ir:.2f} | {tv:.0f} / {tf:.0f} |")
    n = len(rows)
    mv, mr = sum(r[1] for r in rows) / n, sum(r[2] for r in rows) / n
    print(f"| mean | {mv:.2f} | {mr:.2f} | {mr - mv:+.2f} | | |")
    print("\ncommands:\n" + "\n".join(log))


if __name__ == "__main__":
    main()
