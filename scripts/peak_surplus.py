"""``panovocc map``'s peak resident memory above its start-up, split into the memory it holds and the rest
(issue 21's ratio; docs/mapping.md, "The house's peak, ninth pass"): maps SEQ into OUT in a child process as a
user runs it and prints one JSON object.

    python scripts/peak_surplus.py SEQ OUT [map options, e.g. --frames 0:300]

The peak is the child's ``ru_maxrss`` and the start-up its resident memory after the first frame, both as
``make bench-scale`` reads them (``benchmark.scale.timed``, ``frame_costs``); the memory held is
``VoxelMemory.nbytes`` of the map's ``memory.npz`` (``benchmark.scale.memory_figures``); MiB. ``surplus`` = peak
- start-up - held: what the run holds above its start-up besides the memory itself. The ratio the issue bounds
is ``1 + surplus / held``.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path


def main() -> None:
    if len(sys.argv) < 3:
        raise SystemExit(__doc__.splitlines()[4].strip())
    seq, out, extra = sys.argv[1], Path(sys.argv[2]), sys.argv[3:]
    from panovocc_cli.benchmark import panovocc_command
    from panovocc_cli.benchmark.scale import frame_costs, memory_figures, timed

    with tempfile.TemporaryDirectory() as tmp:
        times = Path(tmp) / "frames.csv"
        run = timed(panovocc_command("map", seq, out, "--quiet", "--checkpoint-every", "0", "--frame-times", times,
                                     *extra), Path(tmp) / "map.log")
        start = frame_costs(times)["startup_rss_bytes"] / 2 ** 20
    peak = run["peak_rss_bytes"] / 2 ** 20
    held = memory_figures(out)["memory_bytes"] / 2 ** 20
    print(json.dumps({"map": str(out), "options": extra, "held_mib": round(held, 2), "start_mib": round(start, 1),
                      "peak_mib": round(peak, 1), "above_start_mib": round(peak - start, 1),
                      "ratio": round((peak - start) / held, 3), "surplus_mib": round(peak - start - held, 1)}))


if __name__ == "__main__":
    main()
