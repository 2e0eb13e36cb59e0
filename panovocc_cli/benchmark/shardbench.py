"""``make bench-shards``: frames per second of ``panovocc map`` on 1 and 2 Dask workers (one thread each).

One home (``panovocc synth --seed 0``, its trajectory of ``--frames`` poses) rendered at ``--width``; the same
frames mapped (simulated segmenter, 12-word vocabulary of the sequence's classes) in this process, then on a
local cluster of 1 worker, then of 2 workers (``--repeats`` such pairs, one after the other: the figure is
the median pair's ratio, as this machine's speed drifts between runs), every thread count at 1 (``NUMBA_NUM_THREADS=1``: the target
sets it for this process, the cluster for its workers). The workers are warmed first (one frame each: the
code check, the imports, numba's kernels loaded from its cache); the figure is the integration phase of the
run (the shards, the records appended in frame order, the tree sum and its top added on the client),
frames / seconds. The export (GSC, grid, PLY) and the save are the client's and the same in every arm, so
they are left out of the figure and listed apart. The folders must be the same bytes in every arm (checked).

Prints each arm, the ratio of 2 workers to 1, the bytes a shard sends back (delta records, partial
memory) and the load average; writes ``WORK/shards.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from . import panovocc_command
from .sharded import SHARDS_PER_WORKER




def prepare(work: Path, frames: int, width: int, seed: int = 0) -> Path:
    """The benchmark's sequence (made once): a home of ``seed`` with ``frames`` poses at ``width``."""
    sc, seq = work / "scene", work / "seq"
    if not (sc / "traj.txt").is_file():
        subprocess.run(panovocc_command("synth", sc, "--seed", seed, "--frames", frames, "--overwrite"), check=True)
    if not (seq / "meta.json").is_file():
        subprocess.run(panovocc_command("render", sc, seq, "--width", width, "--seed", seed, "--overwrite"), check=True)
    return seq


def run(work: Path, frames: int = 60, width: int = 512, shards_per_worker: int = SHARDS_PER_WORKER,
        repeats: int = 3) -> dict:
    from ..mapping.config import MapConfig
    from ..mapping.pipeline import run_map
    from .runner import dask_client
    from .sharded import DaskShards

    if os.environ.get("NUMBA_NUM_THREADS") != "1":
        raise PanovoccError("run the shard benchmark with NUMBA_NUM_THREADS=1 (make bench-shards sets it)")
    work.mkdir(parents=True, exist_ok=True)
    seq = prepare(work, frames, width)
    arms = {}
    load0 = os.getloadavg()

    def cfg(name):
        return MapConfig(seq=str(seq), out=str(work / name))

    t0 = time.perf_counter()
    s = run_map(cfg("inproc"), overwrite=True, progress=False)
    arms["in process"] = {"seconds": s["integrated"] * s["ms_per_frame"] / 1e3, "wall": time.perf_counter() - t0,
                          "frames": s["integrated"]}
    files = ("memory.npz", "prediction.npz", "deltas/shard-000000.pvd")
    want = {f: (work / "inproc" / f).read_bytes() for f in files}
    arms["in process"]["frames_per_s"] = arms["in process"]["frames"] / arms["in process"]["seconds"]
    pairs, same = [], True
    for _ in range(max(1, repeats)):  # 1 worker, then 2, again and again: a pair's ratio sees one spell of load
        pair = {}
        for n in (1, 2):
            with dask_client(None, n) as client:
                shards = DaskShards(client, shards_per_worker=shards_per_worker)
                t0 = time.perf_counter()
                s = run_map(cfg(f"w{n}"), overwrite=True, progress=False, shards=shards)
                pair[n] = {**shards.stats, "wall": time.perf_counter() - t0}
                pair[n]["frames_per_s"] = pair[n]["frames"] / pair[n]["seconds"]
            same = same and all((work / f"w{n}" / f).read_bytes() == want[f] for f in files)
        pair["ratio"] = pair[2]["frames_per_s"] / pair[1]["frames_per_s"]
        pairs.append(pair)
    ratios = [p["ratio"] for p in pairs]
    mid = pairs[int(np.argsort(ratios)[(len(ratios) - 1) // 2])]  # the pair of the median ratio (lower middle)
    arms["1 worker"], arms["2 workers"] = mid[1], mid[2]
    w2 = mid[2]
    return {"frames": frames, "width": width, "arms": arms, "ratio_2_to_1": mid["ratio"], "ratios": ratios,
            "pairs": [{str(k): v for k, v in p.items()} for p in pairs], "shards_per_worker": shards_per_worker,
            "same_bytes": same, "cores": os.cpu_count(), "load_before": load0, "load_after": os.getloadavg(),
            "record_bytes_per_frame": w2["record_bytes"] / w2["frames"],
            "partial_bytes_per_shard": w2["partial_bytes"] / w2["shards"], "root_bytes": w2["root_bytes"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--shards-per-worker", type=int, default=SHARDS_PER_WORKER)
    ap.add_argument("--repeats", type=int, default=3, help="pairs of runs (1 worker, 2 workers); the median ratio")
    a = ap.parse_args(argv)
    try:
        r = run(a.work, a.frames, a.width, a.shards_per_worker, a.repeats)
    except PanovoccError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    for name, arm in r["arms"].items():
        extra = (f", {arm['shards']} shards, records {arm['record_bytes'] / 1e6:.1f} MB, partial memories "
                 f"{arm['partial_bytes'] / 1e6:.1f} MB; CPU: shards {arm['shard_cpu_s']:.1f} s on the workers, "
                 f"client {arm['client_cpu_s']:.1f} s" if "shards" in arm else "")
        print(f"{name:11s} {arm['frames_per_s']:6.2f} frames/s ({arm['frames']} frames in {arm['seconds']:.1f} s; "
              f"whole run {arm['wall']:.1f} s{extra})")
    print(f"2 workers / 1 worker: {r['ratio_2_to_1']:.2f}x, the median of {len(r['ratios'])} pairs run one after the "
          f"other ({', '.join(f'{x:.2f}' for x in r['ratios'])}; the arms above are that pair's); a shard sends back {r['record_bytes_per_frame'] / 1e6:.3f} MB "
          f"of records a frame and a partial memory of {r['partial_bytes_per_shard'] / 1e6:.2f} MB (the tree's top, "
          f"added by the client: {r['root_bytes'] / 1e6:.2f} MB); same bytes in every arm: {r['same_bytes']}; load average "
          f"{r['load_before'][0]:.1f} before, {r['load_after'][0]:.1f} after, on {r['cores']} cores")
    (a.work / "shards.json").write_text(json.dumps(r, indent=2, default=float) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
