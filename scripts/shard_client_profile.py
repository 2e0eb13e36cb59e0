"""Where a sharded run's client spends its CPU (docs/sharding.md, "Throughput"): the records kept, the root's
decode and add, the checkpoints, timed one by one around a run of 24 frames of the bench-shards home on one
local worker; the rest of the client's CPU is Dask's scheduler and client loops.

Usage: NUMBA_NUM_THREADS=1 python scripts/shard_client_profile.py work/bench-shards/seq [FRAMES]
"""

import sys
import time


def main(seq: str, frames: int = 24) -> None:
    import panovocc_cli.benchmark.sharded as sh
    from panovocc_cli.benchmark.runner import dask_client
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.mapper import Mapper
    from panovocc_cli.mapping.pipeline import run_map

    cpu: dict = {}

    def timed(owner, name):
        f = getattr(owner, name)

        def run(*a, **k):
            c = time.process_time()
            try:
                return f(*a, **k)
            finally:
                cpu[name] = cpu.get(name, 0.0) + time.process_time() - c
        setattr(owner, name, run)

    for name in ("keep_encoded", "add_sum", "checkpoint"):
        timed(Mapper, name)
    timed(sh, "decode_partial")
    with dask_client(None, 1) as client:
        shards = sh.DaskShards(client)
        run_map(MapConfig(seq=seq, out="/tmp/shard_client_profile", frames=f"0:{frames}"), overwrite=True,
                progress=False, shards=shards)
    st = shards.stats
    print(f"{frames} frames on 1 worker: {st['seconds']:.1f} s wall, shards {st['shard_cpu_s']:.2f} s CPU on the "
          f"worker, client {st['client_cpu_s']:.2f} s CPU, of which " + ", ".join(f"{k} {v:.3f} s" for k, v in cpu.items()))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 24)
