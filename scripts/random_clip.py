"""Write a randomly initialised open_clip model of a real architecture as a folder ``map --segmenter clip:FOLDER``
loads: what a network segmenter costs, measured without its weights (none can be downloaded here). Its
timings are a trained model's (the same layers, the same arithmetic); its labels are noise.

    python scripts/random_clip.py FOLDER [--model ViT-B-16] [--seed 0]

Used for the revise-against-integrate figure where perception is a network's (docs/mapping.md, "Revisions
where perception is a network's"):

    python scripts/random_clip.py W/vitb16
    python -m panovocc_cli.benchmark.scale W --scene house --frames 1200 --segmenter clip:W/vitb16
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--model", default="ViT-B-16", help="an open_clip architecture name")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    if a.folder.exists():
        raise SystemExit(f"{a.folder}: exists (give a new folder)")
    from clip_helpers import write_tiny_clip

    from panovocc_cli.semantics._torch_compat import import_open_clip

    config = import_open_clip().get_model_config(a.model)
    if config is None:
        raise SystemExit(f"{a.model}: not an open_clip architecture")
    write_tiny_clip(a.folder, seed=a.seed, config=config)
    print(a.folder)


if __name__ == "__main__":
    main()
