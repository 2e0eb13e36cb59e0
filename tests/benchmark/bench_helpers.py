"""Helpers of the benchmark tests: the tiny in-process sweep, byte snapshots (the CLI in process: tests/cli_helpers.run_cli).

Scale ``tiny`` (one one-room scene, 6 frames at 128x64), two map methods and one baseline entry.
"""

from __future__ import annotations

from pathlib import Path

TINY_METHODS = "panovocc,wo-gsc,persp-tsdf"


def reproduce(out: Path, cache: Path, client=None, **kw):
    """``run_reproduce`` of the tiny sweep (in process unless ``workers``/``client`` say otherwise)."""
    from panovocc_cli.benchmark.run import ReproduceConfig, run_reproduce

    cfg = ReproduceConfig(out=out, cache=cache, scale="tiny", methods=TINY_METHODS, workers=0, progress=False)
    for k, v in kw.items():
        setattr(cfg, k, v)
    return run_reproduce(cfg, client=client)


def tree_bytes(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
