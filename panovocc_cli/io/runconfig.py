"""A stage's resolved configuration saved beside its outputs (``config.json``), so a run can be repeated.

Where it goes (docs/conventions.md, "Files"):

* a stage that writes a folder (synth, render, map, eval ``--out``, coverage, demo): ``FOLDER/config.json``;
* a stage that writes one file (gt ``OUT.npz``, show ``OUT.png``): ``OUT.config.json`` beside it (the
  file's suffix replaced: ``gt.npz`` -> ``gt.config.json``).

The JSON is the config dataclass's fields (``dataclasses.asdict``) in declaration order, paths as
given, indent 2, a final newline: the same config gives the same bytes. Fields that change nothing in
the outputs (``progress``, ``overwrite``, ``quiet``) are left out.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from .atomic import check_outputs, write_text

CONFIG_NAME = "config.json"
RUNTIME_ONLY = ("progress", "overwrite", "quiet")  # fields that change no output byte


def jsonable(x: Any) -> Any:
    """``x`` with paths as strings, tuples as lists, NaN as null, numpy scalars/arrays as numbers/lists."""
    if is_dataclass(x) and not isinstance(x, type):
        x = asdict(x)
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if hasattr(x, "tolist") and not isinstance(x, (str, bytes)):  # numpy scalar or array
        return jsonable(x.tolist())
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def config_json(cfg: Any) -> str:
    """The text of ``config.json`` for a config dataclass (runtime-only fields dropped)."""
    d = {k: v for k, v in asdict(cfg).items() if k not in RUNTIME_ONLY}
    return json.dumps(jsonable(d), indent=2) + "\n"


def config_path_beside(output_file: str | Path) -> Path:
    """Where a one-file stage's config goes: ``OUT.config.json`` beside ``OUT.ext``."""
    p = Path(output_file)
    return p.with_name(p.stem + "." + CONFIG_NAME)


def check_file_output(out: str | Path, kind: str, overwrite: bool = False, inputs=(), also=()) -> Path:
    """Check a one-file stage's output ``out`` and its ``OUT.config.json`` by one rule, before anything is written.

    The config beside follows the rule of the output it describes (io/atomic.check_output): an existing one is
    replaced only with ``overwrite``, never an input. ``also`` lists the stage's other outputs as (path, kind,
    folder) triples; no two outputs may share a path (io/atomic.check_outputs). Returns the config's path (write it
    with :func:`write_run_config` once the output is written).
    """
    side = config_path_beside(out)
    check_outputs([(out, kind, False), (side, "run config", False), *also], overwrite, inputs=inputs)
    return side


def write_run_config(path: str | Path, cfg: Any) -> Path:
    """Atomically write ``cfg`` (a dataclass) as JSON to ``path``; returns the path."""
    write_text(path, config_json(cfg))
    return Path(path)
