"""The effect of O counting N (issue 26, docs/mapping.md step 6) on a sequence's occupancy IoU.

    python scripts/o_rule_effect.py SEQ GT.npz WORK

Maps SEQ geometry only (``--segmenter none``, no checkpoints) twice, with ``GeometryParams.observe_hits``
False (O counts valid comparisons of a voxel's centre only, the rule before) and True (the default: a frame
that counts in N counts in O), and prints the FreeOcc IoU of each against GT.npz.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq")
    ap.add_argument("gt")
    ap.add_argument("work")
    a = ap.parse_args()

    import panovocc_cli.runtime as rt
    from panovocc_cli.mapping.config import SemanticParams
    from panovocc_cli.mapping.params import GeometryParams
    from panovocc_cli.mapping.pipeline import MapConfig, run_map

    rt.setup()
    for flag in (False, True):
        out = f"{a.work}/observe_hits_{int(flag)}"
        cfg = MapConfig(seq=a.seq, out=out, checkpoint_every=0,
                        geometry=dataclasses.replace(GeometryParams(), observe_hits=flag),
                        semantic=dataclasses.replace(SemanticParams(), segmenter="none"))
        run_map(cfg, overwrite=True, progress=False)
        j = json.loads(subprocess.run([sys.executable, "-m", "panovocc_cli", "eval", f"{out}/prediction.npz", a.gt,
                                       "--json"], capture_output=True, text=True, check=True).stdout)
        print(f"observe_hits={flag}: IoU {j['iou']:.2f}", flush=True)


if __name__ == "__main__":
    main()
