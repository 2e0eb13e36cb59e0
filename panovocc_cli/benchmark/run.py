"""``run_reproduce``: the whole benchmark -- the sweep, then every table and figure in ``results/``.

Output folder (``--out``, default ``results/``)::

    benchmark.json                  the sweep: scale, splits, methods, code fingerprint, commit, availability
    main_<split>.{csv,md,tex}       Table 1 per split (IoU, mIoU, per-class IoU; reported rows)
    per_scene_<split>.csv           the cells the main table pools
    ablation.{csv,md,tex}           Table 2; upstream.{csv,md,tex} Table 3; coverage.{csv,md,tex} Table 4
    figures/coverage_<split>.png    panoramic vs perspective coverage along the first scene's trajectory
    figures/qualitative_<split>.png ground truth beside each method on the first scene
    provenance.md                   every task: its key, label and the panovocc command it equals

Every file is a function of the code and the options only (no time, no host, no cache state), so a rerun
gives the same bytes. CSV files carry per-row provenance columns (data, command, config, code, commit).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from ..config import option, validate_config
from ..errors import PanovoccError
from .splits import SCALES

MARKER = "benchmark.json"


@dataclass
class ReproduceConfig:
    """Options of ``panovocc reproduce``."""

    out: Path = option(Path("results"), flag="--out", help="Folder for the tables and figures (results/).")
    cache: Path = option(Path("work/benchmark-cache"),
                         help="Task cache: finished tasks are kept here and never recomputed (resume).")
    scale: str = option("full", choices=SCALES, help="full (make reproduce-tables) | small (minutes) | tiny (tests).")
    splits: str = option("all", help="Splits: all, or a comma list of pan-replica-synth, pan-holo-synth.")
    methods: str = option("all", help="Methods: all, or a comma list of registry names (docs/benchmark.md).")
    scheduler: str | None = option(None, help="Address of an existing Dask scheduler (tcp://host:8786); "
                                              "default: a local cluster of --workers processes.")
    workers: int = option(2, min=0, max=256, help="Local cluster worker processes, one thread each "
                                                  "(0 = run in this process, one task after the other).")
    progress: bool = option(True, flag="--quiet", negate=True, help="No progress bar.")
    overwrite: bool = option(False, help="Replace a previous reproduce output in --out (never any other files).")


def check_out(out: Path, overwrite: bool) -> None:
    """Refuse an --out folder that holds anything but a previous benchmark output (its ``benchmark.json``)
    and a README; a previous output is replaced only with ``overwrite``."""
    from ..io.atomic import check_output_path

    check_output_path(out, folder=True)
    if not out.is_dir():
        return
    others = [p for p in out.iterdir() if p.name not in ("README.md", ".lock")
              and not (p.is_dir() and (p / MARKER).is_file())]  # e.g. results/small/ beside results/
    if not others:
        return
    if not (out / MARKER).is_file():
        raise PanovoccError(f"is not a panovocc reproduce output (no {MARKER}); refusing to write into it: "
                            "choose another --out", out)
    if not overwrite:
        raise PanovoccError("already holds a reproduce output (pass --overwrite to replace it)", out)


def run_reproduce(cfg: ReproduceConfig, log=sys.stderr, client=None) -> dict:
    """Run the sweep and write the tables and figures; returns a summary.

    Returns
    -------
    {"tables": [paths], "figures": [paths], "tasks": n, "computed": n, "cached": n, "failed": [labels],
     "unavailable": {name: reason}}

    Raises
    ------
    PanovoccError when tasks failed (after writing every table, the failed cells marked).
    """
    from .methods import select_methods
    from .runner import run_tasks
    from .splits import check_scale, select_splits
    from .sweep import build_sweep
    from ..io.atomic import check_writable_folder
    from .tasks import check_cache, code_commit, code_fingerprint

    cfg = validate_config(cfg)
    check_scale(cfg.scale)
    splits, methods = select_splits(cfg.splits), select_methods(cfg.methods)
    out, cache = Path(cfg.out), Path(cfg.cache)
    check_out(out, cfg.overwrite)
    if cache.resolve() == out.resolve() or out.resolve() in cache.resolve().parents:
        raise PanovoccError("the cache must not be inside --out (the results folder is committed)", cache)
    if cache.resolve() in out.resolve().parents:
        raise PanovoccError("--out must not be inside --cache (the results are kept, the cache may be removed)",
                            out)
    check_cache(cache)
    for folder in (out, cache):  # a read-only or /proc path is refused now, not after the sweep
        check_writable_folder(folder)
    sweep = build_sweep(splits, methods, cfg.scale)
    if cfg.progress:
        for (what, name), why in sweep.unavailable.items():
            print(f"{what} {name}: {why}", file=log)
        print(f"{len(sweep.tasks)} tasks ({cfg.scale} scale) -> cache {cache}", file=log, flush=True)
    results = run_tasks(sweep.tasks, cache, cfg.scheduler, cfg.workers, cfg.progress, log, client=client)
    code, commit = code_fingerprint()[:12], code_commit()
    paths = write_results(sweep, results, cache, out, cfg, code, commit)
    status = [r["status"] for r in results.values()]
    failed = sorted(r["label"] for r in results.values() if r["status"] == "failed")
    summary = {"tables": paths["tables"], "figures": paths["figures"], "tasks": len(results),
               "computed": status.count("computed"), "cached": status.count("cached"), "failed": failed,
               "unavailable": {f"{w} {n}": why for (w, n), why in sweep.unavailable.items()}}
    if failed:
        raise PanovoccError(f"{len(failed)} task(s) failed (first: {failed[0]}); their cells say 'failed'; "
                            f"rerun to retry them (finished tasks stay cached)", out)
    return summary


def write_results(sweep, results: dict, cache: Path, out: Path, cfg: ReproduceConfig, code: str,
                  commit: str) -> dict:
    """Every table and figure of a finished sweep into ``out``."""
    import shutil

    from ..io.atomic import atomic_path, output_folder, write_text
    from ..io.tables import csv_text, latex_text, markdown_text
    from . import tables as T
    from .tasks import counts_from_json, task_folder

    errors = {k: r.get("error", "") for k, r in results.items() if r["status"] == "failed"}

    def counts_of(task):
        if task.key in errors or task.key not in results:
            return None
        d = json.loads((task_folder(cache, task.kind, task.key) / "counts.json").read_text())
        return {m: counts_from_json(c) for m, c in d.items()}

    scores = T.Scores(sweep, counts_of, errors)
    split_names = [s.name for s in sweep.splits]
    tables = [T.main_table(sweep, scores, s) for s in split_names]
    tables += [T.per_scene_table(sweep, counts_of, s) for s in split_names if s in sweep.scenes]
    if "pan-replica-synth" in split_names:
        tables.append(T.ablation_table(sweep, scores))
    tables.append(T.upstream_table(sweep, scores))
    cov = {k: (None if t.key in errors else results[t.key].get("summary")) for k, t in sweep.coverage.items()}
    tables.append(T.coverage_table(sweep, cov))

    written, figures = [], []
    with output_folder(out) as d:
        for t in tables:
            prov_cols = ["data", "command", "config", "code", "commit"]
            csv_rows = [r + [p["data"], p["command"], p["config"], code, commit] for r, p in zip(t.rows, t.provenance)]
            write_text(d / f"{t.stem}.csv", csv_text(t.header + prov_cols, csv_rows))
            written.append(d / f"{t.stem}.csv")
            if t.stem.startswith("per_scene_"):
                continue
            md = [f"## {t.title}", "", markdown_text(t.header, t.rows).rstrip("\n"), ""]
            md += [f"- {n}" for n in t.notes]
            md += ["", f"Provenance: code {code}, commit {commit}. Per row (data; command; config hash):", ""]
            md += [f"- {p['row']}: {p['data']}; `{p['command']}`; {p['config']}" for p in t.provenance
                   if p["command"] != "-"]
            write_text(d / f"{t.stem}.md", "\n".join(md) + "\n")
            tex = [f"% {t.title}. Produced by panovocc reproduce --scale {sweep.scale}; code {code}, commit "
                   f"{commit}; per-row provenance in {t.stem}.csv", latex_text(t.header, t.rows)]
            write_text(d / f"{t.stem}.tex", "\n".join(tex))
            written += [d / f"{t.stem}.md", d / f"{t.stem}.tex"]
        # figures: the first scene's coverage curves and the qualitative picture, per split
        for split in split_names:
            for kind, task, name in (("coverage", _first_coverage(sweep, split), "coverage/coverage.png"),
                                     ("qualitative", sweep.shows.get(split), "qualitative.png")):
                if task is None or task.key in errors or task.key not in results:
                    continue
                src = task_folder(cache, task.kind, task.key) / name
                dst = d / "figures" / f"{kind}_{split}.png"
                dst.parent.mkdir(parents=True, exist_ok=True)
                with atomic_path(dst) as tmp:
                    shutil.copyfile(src, tmp)
                figures.append(dst)
        write_text(d / "provenance.md", _provenance_md(sweep, results, code, commit))
        write_text(d / MARKER, json.dumps(_marker(sweep, cfg, code, commit), indent=2) + "\n")
    return {"tables": [str(p) for p in written], "figures": [str(p) for p in figures]}


def _first_coverage(sweep, split: str):
    scenes = sweep.scenes.get(split, [])
    return sweep.coverage.get((split, scenes[0].name)) if scenes else None


def _provenance_md(sweep, results: dict, code: str, commit: str) -> str:
    lines = ["# Provenance of every task", "",
             f"Code fingerprint {code} (panovocc_cli sources and version), commit {commit}. Paths are relative "
             "to the task cache (`--cache`); each task's folder is `KIND/KEY16`.", "",
             "| task | key | equivalent command |", "|---|---|---|"]
    for t in sweep.tasks:
        r = results.get(t.key, {})
        cmd = r.get("command") or f"failed: {r.get('error', '?')}"
        lines.append(f"| {t.label} | {t.short} | `{cmd}` |")
    return "\n".join(lines) + "\n"


def _marker(sweep, cfg: ReproduceConfig, code: str, commit: str) -> dict:
    return {"kind": "panovocc reproduce", "scale": sweep.scale, "splits": [s.name for s in sweep.splits],
            "methods": [m.name for m in sweep.methods], "code": code, "commit": commit,
            "command": f"panovocc reproduce --scale {sweep.scale} --splits {cfg.splits} --methods {cfg.methods}",
            "unavailable": {f"{w} {n}": why for (w, n), why in sorted(sweep.unavailable.items())},
            "scenes": {s: [vars(x) for x in sc] for s, sc in sweep.scenes.items()},
            "tasks": len(sweep.tasks)}
