"""Where ``panovocc map``'s resident memory goes, frame by frame and phase by phase (issue 21, docs/mapping.md
"Memory layout"): runs ``panovocc map ARGS`` in this process and writes one JSON object to OUT.

    python scripts/map_rss_phases.py OUT.json -- map SEQ MAP --checkpoint-every 0 [--frames 0:300]
    PK_MODE=noreader+syncwriter python scripts/map_rss_phases.py ...   # a variant of scripts/map_overlap_variants.py

Per frame: resident memory (``/proc/self/status`` VmRSS, MiB) after the frame, the memory held
(``VoxelMemory.nbytes``), the frame box's voxels (``psvf.update.frame_box``) and the delta's bytes (keys and
channels); every 25th frame also the resident memory by kind (``/proc/self/smaps``: the main heap, other
anonymous memory, file mappings) and glibc's arenas (``malloc_info``: each arena's size and the free memory
it keeps). Around the export, the grid and PLY writes and the save: the same, before and after; and the peak
of each phase (a thread samples VmRSS every 3 ms). Linux and glibc only.
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import sys
import threading
import time


def _status(field: str) -> float:
    for line in open("/proc/self/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _smaps() -> dict:
    """Resident MiB of the main heap, other anonymous mappings and file mappings."""
    tot = {"heap": 0.0, "anon": 0.0, "file": 0.0}
    cur = "file"
    for line in open("/proc/self/smaps"):
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            p = line.split()
            name = p[5] if len(p) > 5 else ""
            cur = "heap" if name == "[heap]" else ("anon" if name == "" else "file")
        elif line.startswith("Rss:"):
            tot[cur] += int(line.split()[1]) / 1024
    return tot


class _Malloc:
    def __init__(self):
        self.libc = ctypes.CDLL("libc.so.6")
        self.libc.open_memstream.restype = ctypes.c_void_p
        self.libc.fclose.argtypes = [ctypes.c_void_p]
        self.libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]

    def arenas(self) -> list:
        """Per glibc arena: [number, MiB mapped, MiB free in it]."""
        buf, size = ctypes.c_char_p(), ctypes.c_size_t()
        f = self.libc.open_memstream(ctypes.byref(buf), ctypes.byref(size))
        self.libc.malloc_info(0, f)
        self.libc.fclose(f)
        out = []
        for m in re.finditer(r'<heap nr="(\d+)">(.*?)</heap>', buf.value.decode(), re.S):
            body = m.group(2)
            free = sum(int(v) for k, v in re.findall(r'<total type="(\w+)" count="\d+" size="(\d+)"/>', body)
                       if k in ("fast", "rest"))
            system = re.search(r'<system type="current" size="(\d+)"/>', body)
            out.append([int(m.group(1)), round(int(system.group(1)) / 2 ** 20, 2) if system else 0.0,
                        round(free / 2 ** 20, 2)])
        return out


def main() -> None:
    if len(sys.argv) < 4 or sys.argv[2] != "--":
        raise SystemExit(__doc__.splitlines()[3].strip())
    out_path, argv = sys.argv[1], sys.argv[3:]
    malloc = _Malloc()
    phase, peaks, stop = ["start"], {}, [False]

    def sampler():
        while not stop[0]:
            r, ph = _status("VmRSS"), phase[0]
            peaks[ph] = max(peaks.get(ph, 0.0), r)
            time.sleep(0.003)

    from panovocc_cli.runtime import setup

    setup()  # before the sampler thread starts: its malloc arena then follows the command's settings
    if os.environ.get("PK_MODE"):  # a variant of the frame pipeline (scripts/map_overlap_variants.py)
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import map_overlap_variants

        map_overlap_variants.apply()
    threading.Thread(target=sampler, daemon=True).start()
    from panovocc_cli.cli import main as cli_main
    from panovocc_cli.mapping import mapper as mapper_mod
    from panovocc_cli.mapping import pipeline
    from panovocc_cli.mapping.psvf import update

    frames, events, boxes, deltas = [], [], [], []
    integrate, delta_of, box_of = mapper_mod.Mapper.integrate, mapper_mod.Mapper._delta, update.frame_box

    def frame_box(*a, **k):
        lo, shape = box_of(*a, **k)
        boxes.append(int(shape[0]) * int(shape[1]) * int(shape[2]))
        return lo, shape

    def measured_delta(self, *a, **k):
        d = delta_of(self, *a, **k)
        deltas.append(int(sum(p.keys.nbytes + sum(v.nbytes for v in p.channels.values()) for p in d.parts)))
        return d

    def measured_integrate(self, frame, *a, **k):
        phase[0] = "frame"
        nb, nd = len(boxes), len(deltas)
        r = integrate(self, frame, *a, **k)
        rec = {"i": len(frames), "rss_mib": _status("VmRSS"), "memory_bytes": sum(self.memory.nbytes().values()),
               "box_voxels": boxes[-1] if len(boxes) > nb else 0, "delta_bytes": deltas[-1] if len(deltas) > nd else 0}
        if len(frames) % 25 == 0:
            rec.update(smaps=_smaps(), arenas=malloc.arenas())
        frames.append(rec)
        phase[0] = "between"
        return r

    def around(owner, name):
        f = getattr(owner, name)

        def g(*a, **k):
            phase[0] = name
            rec = {"phase": name, "before_mib": _status("VmRSS"), "smaps_before": _smaps(),
                   "arenas_before": malloc.arenas()}
            try:
                return f(*a, **k)
            finally:
                rec.update(after_mib=_status("VmRSS"), smaps_after=_smaps(), arenas_after=malloc.arenas())
                events.append(rec)
                phase[0] = name + " done"

        setattr(owner, name, g)

    update.frame_box = frame_box
    mapper_mod.Mapper._delta = measured_delta
    mapper_mod.Mapper.integrate = measured_integrate
    around(mapper_mod.Mapper, "export")
    around(pipeline, "write_exports")
    around(mapper_mod.Mapper, "save")
    try:
        cli_main(argv)
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    stop[0] = True
    with open(out_path, "w") as f:
        json.dump({"argv": argv, "peak_mib": _status("VmHWM"), "phase_peaks_mib": peaks, "frames": frames,
                   "events": events}, f)
    print(json.dumps({"peak_mib": _status("VmHWM"), "startup_mib": frames[0]["rss_mib"] if frames else None,
                      "phase_peaks_mib": {k: round(v, 1) for k, v in peaks.items()}}))


if __name__ == "__main__":
    main()
