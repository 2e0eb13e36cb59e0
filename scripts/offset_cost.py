"""What the surface-offset channel P costs (docs/mapping.md, "Face resolution"): the same frames mapped with
``geometry.offsets`` on and off in one process, in alternating rounds.

    python scripts/offset_cost.py MAP [--frames 30] [--rounds 2]

MAP is a finished map folder (its config.json gives the sequence, poses and parameters). Prints one JSON
object: per arm the CPU seconds per frame (``time.process_time``, each round's frames; the ratio on over off
of the summed times), the memory's bytes (``VoxelMemory.nbytes``: geometry, sparse pages and rows, table),
the voxels holding a P row, and the delta record bytes per frame (``rpu.encode_record`` of each frame's
delta, as the delta log stores it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()

    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.pipeline import load_config, sequence_frames
    from panovocc_cli.mapping.rpu import encode_record

    cfg = load_config(args.map)
    frames = sequence_frames(cfg, Sequence(cfg.seq))
    poses = Mapper.load(args.map)
    ids = poses.frame_ids[:args.frames]
    data = []
    for i in ids:
        f = frames(i)
        f.T_world_cam = poses.pose(i)
        data.append(f)
    poses.close()
    base = cfg.mapper_config()
    arms = {"on": dataclasses.replace(base, geometry=dataclasses.replace(base.geometry, offsets=True)),
            "off": dataclasses.replace(base, geometry=dataclasses.replace(base.geometry, offsets=False))}
    cpu = {k: 0.0 for k in arms}
    out = {}
    for r in range(args.rounds):
        for name in (("on", "off") if r % 2 == 0 else ("off", "on")):
            m = Mapper(arms[name])
            rec = 0
            t0 = time.process_time()
            for f in data:
                m.integrate(f)
            cpu[name] += time.process_time() - t0
            for i in m.frame_ids:
                rec += len(encode_record(m._rpu.store.get(i), m.pose(i)))
            b = m.memory.nbytes()
            rows = m.memory.n_rows
            out[name] = {"memory_bytes": {k: int(v) for k, v in b.items()}, "allocated_voxels": m.memory.allocated_voxels,
                         "p_rows": int(rows), "record_bytes_per_frame": round(rec / len(data), 1)}
            m.close()
    for name in arms:
        out[name]["cpu_s_per_frame"] = round(cpu[name] / (args.rounds * len(data)), 4)
    out["cpu_ratio_on_over_off"] = round(cpu["on"] / cpu["off"], 3)
    extra = sum(out["on"]["memory_bytes"].values()) - sum(out["off"]["memory_bytes"].values())
    out["p_bytes_per_row"] = round(extra / max(out["on"]["p_rows"], 1), 1)
    out["frames"] = len(data)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
