"""Process settings for the toolkit's kernels, applied by one explicit call: :func:`setup`.

Importing ``panovocc_cli`` (or any module of it) changes nothing in the process. The command line
calls :func:`setup` before it runs a command; a library user who maps or renders from Python calls it
once, first thing, before numba's parallel kernels run::

    import panovocc_cli.runtime
    panovocc_cli.runtime.setup()

What it does, and why (figures: docs/mapping.md, "Speed"):

* ``NUMBA_THREADING_LAYER_PRIORITY=omp workqueue tbb``: numba's parallel kernels use OpenMP (libgomp,
  installed with open3d's Debian dependencies) and never try TBB first (the default order tries TBB
  and warns on every run when the installed TBB is too old).
* ``OMP_WAIT_POLICY=passive``: OpenMP workers sleep at barriers instead of spinning (~300k rounds by
  default). On the 2-core machines this runs on, shared with other jobs, a spinning worker competes
  with the thread it waits for: the geometric update collapsed from ~10 to 66-130 ms/frame under load.
  libgomp reads it when numba first loads it, so :func:`setup` must come before the first parallel
  kernel runs.
* glibc ``mallopt``: keep freed memory in the process (:func:`keep_freed_heap`). (``revise`` also kept
  freed blocks of any size until 2026-12-06, when it had become 2.7 % slower with it: docs/mapping.md, "Revise
  at building scale".)

It also holds the one memory check of the commands (:func:`check_memory`): a command that would allocate
more than it can have refuses in one line before any work, instead of being killed for memory.

Environment values the user already set are kept (``OMP_WAIT_POLICY=active panovocc map ...`` spins).
Calling :func:`setup` again does nothing more. Called after numba was imported, it makes numba read its
settings again; it must still come before the first parallel kernel runs (libgomp reads
``OMP_WAIT_POLICY`` once, when it is loaded).
"""

from __future__ import annotations

import os
import sys

ENV_DEFAULTS = {
    "NUMBA_THREADING_LAYER_PRIORITY": "omp workqueue tbb",
    "OMP_WAIT_POLICY": "passive",
}
"""Environment variables :func:`setup` sets when the user has not set them."""

# glibc malloc: a frame's update allocates ~20 MB of temporaries (kernels, the dense support /
# free-space grids, the delta) and frees them; by default glibc hands the top of its heap back to the
# kernel once over 2x its mmap threshold is free, so every frame faulted ~4200 fresh pages back in. On
# the 2-core machine under load that made the update 22-130 ms/frame instead of 9-10 (same bytes). A
# fixed mmap threshold of 32 MiB (the default's ceiling) and a 256 MiB trim threshold keep the pages;
# the process keeps its peak heap (about one frame's).
HEAP_TRIM_BYTES = 256 * 2 ** 20
HEAP_MMAP_BYTES = 32 * 2 ** 20
# One malloc arena for every thread (M_ARENA_MAX 1): the frame reader and the delta writer beside the loop
# otherwise get arenas of their own, each kept at its own peak (14 and 8 MiB mapped, 11 and 6 MiB of it free
# at the end of the 1,200-frame house), which the loop's frames can never reuse; in the one heap, what one
# thread frees the next allocation of any thread reuses (docs/mapping.md, "The per-frame working set").
HEAP_ARENAS = 1

_done: dict | None = None

MEMORY_SHARE = 0.8
"""Largest share of the memory available now that one command's estimate may ask for (:func:`check_memory`)."""


def keep_freed_heap() -> bool:
    """Set glibc's ``M_TRIM_THRESHOLD`` / ``M_MMAP_THRESHOLD`` / ``M_ARENA_MAX`` (see above) for this process.

    Returns
    -------
    bool
        True when all three were set; False where the C library is not glibc (nothing changed).
    """
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(-1, HEAP_TRIM_BYTES)) and bool(libc.mallopt(-3, HEAP_MMAP_BYTES)) and bool(
            libc.mallopt(-8, HEAP_ARENAS))
    except (OSError, AttributeError):
        return False


def release_freed_heap() -> bool:
    """Hand the heap memory that is free back to the kernel now (glibc ``malloc_trim(0)``): what
    :func:`keep_freed_heap` kept for the per-frame updates, once they are done (before a run's export, so
    the export's own temporaries do not stack on a frame's). True when glibc did it."""
    import ctypes

    try:
        return bool(ctypes.CDLL("libc.so.6").malloc_trim(0))
    except (OSError, AttributeError):
        return False


def quick_exit(code: int = 0) -> None:
    """End the process now with ``code``, without the interpreter's teardown; called by the ``panovocc`` console
    script and ``python -m panovocc_cli`` (:func:`panovocc_cli.cli.entry`) once a command has succeeded, never by
    library code (it does not return).

    A command's outputs are written and closed before it returns (every file goes through a temporary name and
    a rename, its writer threads joined), so what the teardown would still do is free the objects and unload
    the modules: about 0.2 s after ``panovocc map`` of the bench's 40 frames at 1024x512, 7 % of the whole
    process (docs/mapping.md, "Speed"). What it would do that matters is done here first: the ``atexit``
    handlers run (the thread pools' joins, ``weakref.finalize`` hooks, a Rerun recording's flush) and standard
    output and error are flushed. Where a thread that is not a daemon is still alive, the process exits as it
    normally would (the interpreter then waits for it), so nothing running is cut short."""
    import atexit
    import threading

    main = threading.main_thread()
    if any(t is not main and t.is_alive() and not t.daemon for t in threading.enumerate()):
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # a closed pipe: the exit status the interpreter gives it
            code = code or 120
    os._exit(code)


def available_memory() -> int:
    """Bytes of memory available to a new allocation (``MemAvailable`` of /proc/meminfo; else physical)."""
    from pathlib import Path

    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def process_status_mb(field: str) -> float:
    """This process's ``field`` of /proc/self/status (``VmRSS``, ``VmHWM``: the peak), in MB; the measuring
    scripts' one reader (scripts/export_ab.py, export_rss.py, memory_save_peak.py)."""
    from pathlib import Path

    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024  # kB -> MB
    raise RuntimeError(f"/proc/self/status has no {field}")


def check_memory(need: float, what: str, advice: str, path=None) -> None:
    """Refuse work whose memory estimate does not fit: one line, before anything is allocated or written.

    Parameters
    ----------
    need : bytes the work would hold at once (an estimate; any float, ``inf`` included)
    what : what needs it, for the message (``"--box 1e9,1e9,1e9 at 0.08 m: 3 frames of 1e10^3 voxels"``)
    advice : what to change (``"choose a smaller --box"``)
    path : the file or folder the message names, if any

    Raises
    ------
    PanovoccError
        When ``need`` exceeds :data:`MEMORY_SHARE` of :func:`available_memory`:
        ``"{what} needs about X GiB of memory; Y GiB is available: {advice}"``.
    """
    from .errors import PanovoccError

    have = available_memory()
    if not need <= MEMORY_SHARE * have:
        shown = f"{need / 2 ** 30:.1f}" if need < 2.0 ** 80 else f"{need / 2 ** 30:.2g}"
        raise PanovoccError(f"{what} needs about {shown} GiB of memory; {have / 2 ** 30:.1f} GiB is available: "
                            f"{advice}", path)


def setup() -> dict:
    """Apply the toolkit's process settings once (idempotent; a second call returns the first's answer).

    Returns
    -------
    dict
        ``{"env": {name: value in effect}, "heap": bool}``: the environment variables of
        :data:`ENV_DEFAULTS` as they now are (the user's own value where one was set), and whether
        glibc's heap thresholds were set.
    """
    global _done
    if _done is None:
        env = {k: os.environ.setdefault(k, v) for k, v in ENV_DEFAULTS.items()}
        numba_config = sys.modules.get("numba.core.config")
        if numba_config is not None:  # numba was imported first: it read its settings then; read them again
            numba_config.reload_config()
        _done = {"env": env, "heap": keep_freed_heap()}
    return _done
