"""``make bench-shards``: frames per second of ``panovocc map`` on 1 and 2 Dask workers (one thread each).

One home (``panovocc synth --seed 0``, its trajectory of ``--frames`` poses) rendered at ``--width``; the same
frames mapped (simulated segmenter, 12-word vocabulary of the sequence's classes) in this process, then on a
local cluster of 1 worker, then of 2 workers, every thread count at 1 (``NUMBA_NUM_THREADS=1``: the target
sets it for this process, the cluster for its workers). The workers are warmed first (one frame each: the
code check, the imports, numba's kernels loaded from its cache); the figure is the integration phase of the
run (the shards, the records appended in frame order, the tree sum and its root added on the client),
frames / seconds. The export (GSC, grid, PLY) and the save are the client's and the same in every arm, so
they are left out of the figure and listed apart. The three folders must be the same bytes (checked).

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

from ..errors import PanovoccError
from . import panovocc_command




def prepare(work: Path, frames: int, width: int, seed: int = 0) -> Path:
    """The benchmark's sequence (made once): a home of ``seed`` with ``frames`` poses at ``width``."""
    sc, seq = work / "scene", work / "seq"
    if not (sc / "traj.txt").is_file():
        subprocess.run(panovocc_command("synth", sc, "--seed", seed, "--frames", frames, "--overwrite"), check=True)
    if not (seq / "meta.json").is_file():
        subprocess.run(panovocc_command("render", sc, seq, "--width", width, "--seed", seed, "--overwrite"), check=True)
    return seq


def run(work: Path, frames: int = 60, width: int = 512, shards_per_worker: int = 4) -> dict:
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
    for n in (1, 2):
        with dask_client(None, n) as client:
            shards = DaskShards(client, shards_per_worker=shards_per_worker)
            t0 = time.perf_counter()
            s = run_map(cfg(f"w{n}"), overwrite=True, progress=False, shards=shards)
            arms[f"{n} worker{'s' if n > 1 else ''}"] = {**shards.stats, "wall": time.perf_counter() - t0}
    for a in arms.values():
        a["frames_per_s"] = a["frames"] / a["seconds"]
    same = all((work / f"w{n}" / f).read_bytes() == (work / "inproc" / f).read_bytes()
               for n in (1, 2) for f in ("memory.npz", "prediction.npz", "deltas/shard-000000.pvd"))
    w1, w2 = arms["1 worker"], arms["2 workers"]
    return {"frames": frames, "width": width, "arms": arms, "ratio_2_to_1": w2["frames_per_s"] / w1["frames_per_s"],
            "same_bytes": same, "cores": os.cpu_count(), "load_before": load0, "load_after": os.getloadavg(),
            "record_bytes_per_frame": w2["record_bytes"] / w2["frames"],
            "partial_bytes_per_shard": w2["partial_bytes"] / w2["shards"], "root_bytes": w2["root_bytes"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--shards-per-worker", type=int, default=4)
    a = ap.parse_args(argv)
    try:
        r = run(a.work, a.frames, a.width, a.shards_per_worker)
    except PanovoccError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    for name, arm in r["arms"].items():
        extra = (f", {arm['shards']} shards, records {arm['record_bytes'] / 1e6:.1f} MB, partial memories "
                 f"{arm['partial_bytes'] / 1e6:.1f} MB; CPU: shards {arm['shard_cpu_s']:.1f} s on the workers, "
                 f"client {arm['client_cpu_s']:.1f} s" if "shards" in arm else "")
        print(f"{name:11s} {arm['frames_per_s']:6.2f} frames/s ({arm['frames']} frames in {arm['seconds']:.1f} s; "
              f"whole run {arm['wall']:.1f} s{extra})")
    print(f"2 workers / 1 worker: {r['ratio_2_to_1']:.2f}x; a shard sends back {r['record_bytes_per_frame'] / 1e6:.3f} MB "
          f"of records a frame and a partial memory of {r['partial_bytes_per_shard'] / 1e6:.2f} MB (the root: "
          f"{r['root_bytes'] / 1e6:.2f} MB); same bytes in every arm: {r['same_bytes']}; load average "
          f"{r['load_before'][0]:.1f} before, {r['load_after'][0]:.1f} after, on {r['cores']} cores")
    (a.work / "shards.json").write_text(json.dumps(r, indent=2, default=float) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
