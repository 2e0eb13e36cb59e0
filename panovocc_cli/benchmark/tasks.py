"""The task graph of a sweep: one task per stage and scene, keyed by what determines its output.

A :class:`Task` is ``kind`` (synth, gt, render, poses, map, baseline, eval, coverage, show), its
``params`` (a JSON object) and the tasks it reads (``deps``). Its key is the SHA-256 of the kind, the
params, the deps' keys and the code fingerprint (a hash of the package's source and version,
:func:`code_fingerprint`): a Merkle chain, so a key changes exactly when the task's config, any input's
config or the code changes. Every stage is deterministic (seeded), so equal keys mean equal bytes.

Cache layout (``CACHE/``)::

    KIND/KEY16/             a finished task's outputs (KEY16: the key's first 16 hex digits)
    KIND/KEY16/task.json    written last, inside the folder before it is renamed into place: the marker
    KIND/.KEY16.tmp.*       a task in progress, flock'ed by its process while it runs (a sweep starting
                            removes the unlocked ones: what a killed task left)
    _events/computed/       one empty file per task computed (KEY16.PID.NS): what actually ran

:func:`execute` runs one task (on a Dask worker or in process): a task whose folder is complete is not
run again (``status: cached``); otherwise it computes into a temporary folder and renames it into place,
so an interrupted sweep never leaves a half-written task, and resumes where it stopped.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import PanovoccError

TASK_FILE = "task.json"
EVENTS = "_events/computed"
KINDS = ("synth", "gt", "render", "poses", "map", "baseline", "eval", "coverage", "show")
# modules whose text changes no task output: the command line, and the benchmark's graph building, tables,
# runner and speed benchmarks (a task's output is a function of its kind, params and inputs, run by the stages
# below and the library; what the graph puts in the params is in the key already). Left out of the key, but
# for the benchmark modules a task imports: this one and the methods registry (the map task's command line,
# methods.map_cli_flags) with what it imports (tests/benchmark/test_tasks.py checks the list).
_NOT_IN_FINGERPRINT = ("cli/", "benchmark/")
_IN_FINGERPRINT = ("benchmark/tasks.py", "benchmark/methods.py", "benchmark/available.py")


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 (hex) of the package version and the source of every module a task can run.

    Every ``panovocc_cli/**/*.py`` except the command line and the benchmark package other than its stage
    functions (:data:`_NOT_IN_FINGERPRINT`), by relative path and content.
    """
    from .. import __version__

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(f"panovocc {__version__}\n".encode())
    for p in sorted(root.rglob("*.py")):
        rel = p.relative_to(root).as_posix()
        if rel.startswith(_NOT_IN_FINGERPRINT) and rel not in _IN_FINGERPRINT:
            continue
        h.update(rel.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def check_code(code: str, what: str, theirs: str) -> None:
    """Refuse to run on a worker whose :func:`code_fingerprint` is not ``code`` (the client's): one line
    naming ``what`` runs and ``theirs`` (who sent it)."""
    if code != code_fingerprint():
        raise PanovoccError(f"{what}: this worker runs other code ({code_fingerprint()[:12]}) than {theirs} "
                            f"({code[:12]}); workers and client must share one panovocc checkout")


def code_commit() -> str:
    """The last git commit that changed the package (``panovocc_cli/``), ``+dirty`` when the working tree
    has uncommitted changes there; ``unknown`` outside a git checkout. Stable across commits that touch
    only results or docs, so rerunning at a later such commit names the same code."""
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "-C", str(root), "log", "-1", "--format=%H", "--", "panovocc_cli"],
                              capture_output=True, text=True, timeout=20)
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "panovocc_cli"],
                               capture_output=True, text=True, timeout=20)
        return head.stdout.strip()[:12] + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@dataclass(frozen=True)
class Task:
    """One node of the graph.

    kind : a stage (:data:`KINDS`); params : its config (JSON-able, sorted on hashing); deps : input tasks
    label : a short readable name (``map wo-psvf pan-replica-synth/r0``); code : the code fingerprint
    """

    kind: str
    params: dict
    deps: tuple["Task", ...] = ()
    label: str = ""
    code: str = ""
    key: str = field(init=False, compare=False)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown task kind {self.kind!r}")
        body = {"kind": self.kind, "params": self.params, "deps": [d.key for d in self.deps], "code": self.code}
        object.__setattr__(self, "key", hashlib.sha256(_canonical(body).encode()).hexdigest())

    def __hash__(self) -> int:
        return hash(self.key)

    def __eq__(self, other) -> bool:
        return isinstance(other, Task) and other.key == self.key

    @property
    def short(self) -> str:
        return self.key[:16]

    @property
    def dask_key(self) -> str:
        return f"{self.kind}-{self.short}"

    def folder(self, cache: str | Path) -> Path:
        return Path(cache) / self.kind / self.short

    def to_dict(self) -> dict:
        """What a worker needs (plain data: the task's own fields and its deps' kinds and keys)."""
        return {"kind": self.kind, "params": self.params, "key": self.key, "label": self.label,
                "code": self.code, "deps": [{"kind": d.kind, "key": d.key} for d in self.deps]}


def task_folder(cache: str | Path, kind: str, key: str) -> Path:
    return Path(cache) / kind / key[:16]


def read_done(cache: str | Path, kind: str, key: str) -> dict | None:
    """The ``task.json`` of a finished task (None when the task has not finished, or its folder holds another
    key's output)."""
    p = task_folder(cache, kind, key) / TASK_FILE
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and d.get("key") == key else None


def topological(tasks) -> list[Task]:
    """The tasks and everything they depend on, each once, inputs before the tasks that read them."""
    seen: dict[str, Task] = {}

    def visit(t: Task) -> None:
        if t.key in seen:
            return
        for d in t.deps:
            visit(d)
        seen[t.key] = t

    for t in tasks:
        visit(t)
    return list(seen.values())


def check_cache(cache: str | Path) -> None:
    """Refuse a ``--cache`` folder that holds anything but a task cache's entries (``KIND/`` folders and
    ``_events/``): a sweep never writes its tasks into a folder of other files."""
    cache = Path(cache)
    if not cache.is_dir():
        return
    top = EVENTS.split("/")[0]
    others = sorted(p.name for p in cache.iterdir() if not (p.is_dir() and p.name in (*KINDS, top)))
    if others:
        raise PanovoccError(f"is not a panovocc task cache (it holds {others[0]!r}); choose another --cache (an "
                            "empty or new folder)", cache)


def clean_stale(cache: str | Path) -> int:
    """Remove temporary task folders a killed sweep left (``KIND/.KEY16.tmp.*``); returns how many.

    A task in progress holds an flock on its temporary folder (:func:`_live_tmp`), so a folder that is
    locked belongs to a live run (this sweep's or another sharing the cache) and is kept; a killed task's
    lock died with it.
    """
    from ..io.lock import take_flock

    n = 0
    for kind in KINDS:
        d = Path(cache) / kind
        if d.is_dir():
            for tmp in d.glob(".*.tmp.*"):
                try:
                    fd = take_flock(tmp)
                except FileNotFoundError:  # finished or removed meanwhile
                    continue
                except OSError:  # not a folder we can open: not ours to judge; a leftover all the same
                    fd = -1
                if fd is None:
                    continue  # live
                try:
                    shutil.rmtree(tmp, ignore_errors=True)
                finally:
                    if fd >= 0:
                        os.close(fd)
                n += 1
    return n


def _live_tmp(parent: Path, key: str) -> tuple[Path, int]:
    """A new temporary task folder in ``parent`` and an fd holding its flock (closing it marks it stale)."""
    from ..io.lock import take_flock

    while True:
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}.tmp.", dir=parent))
        try:
            return tmp, take_flock(tmp, wait=True)  # waits while a cleaner that got there first removes it
        except FileNotFoundError:
            continue


# --------------------------------------------------------------------------------------- execution
def execute(task: dict, cache: str, *deps_done: Any) -> dict:
    """Run one task unless its output is already in the cache; returns its ``task.json`` content plus
    ``status`` (``computed`` | ``cached``) and ``seconds``.

    ``deps_done`` are the inputs' results (Dask passes them once the inputs finished; only their order
    matters here: the inputs' folders are found from their keys). Called on a worker, so it applies the
    process settings (:func:`panovocc_cli.runtime.setup`) and refuses to run code other than the code the
    key was computed for.
    """
    from ..runtime import setup

    setup()
    kind, key = task["kind"], task["key"]
    done = read_done(cache, kind, key)
    if done is not None:
        return {**done, "status": "cached", "seconds": 0.0}
    if task["code"]:
        check_code(task["code"], f"task {task['label']}", "the sweep")
    final = task_folder(cache, kind, key)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp, held = _live_tmp(final.parent, key)
    t0 = time.perf_counter()
    try:
        deps = [task_folder(cache, d["kind"], d["key"]) for d in task["deps"]]
        outputs, command, summary = STAGES[kind](task["params"], tmp, deps, Path(cache))
        record = {"key": key, "kind": kind, "label": task["label"], "params": task["params"],
                  "deps": [d["key"] for d in task["deps"]], "code": task["code"], "command": command,
                  "outputs": outputs, "summary": summary}
        (tmp / TASK_FILE).write_text(json.dumps(record, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        try:
            os.replace(tmp, final)
        except OSError:  # another worker finished the same task first: keep its output
            if read_done(cache, kind, key) is None:
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        os.close(held)
    ev = Path(cache) / EVENTS
    ev.mkdir(parents=True, exist_ok=True)
    (ev / f"{key[:16]}.{os.getpid()}.{time.time_ns()}").touch()
    return {**record, "status": "computed", "seconds": time.perf_counter() - t0}


def computed_events(cache: str | Path) -> dict[str, int]:
    """How many times each task (KEY16) was computed in this cache (from ``_events/computed``)."""
    counts: dict[str, int] = {}
    d = Path(cache) / EVENTS
    if d.is_dir():
        for p in d.iterdir():
            k = p.name.split(".")[0]
            counts[k] = counts.get(k, 0) + 1
    return counts


def _rel(p: Path, cache: Path) -> str:
    """A path as it will be once the task is in place (relative to the cache), for the command lines."""
    parts = p.resolve().relative_to(cache.resolve()).parts
    if len(parts) >= 2 and ".tmp." in parts[1]:
        parts = (parts[0], parts[1][1:17]) + parts[2:]
    return "/".join(parts)


# ------------------------------------------------------------------------------------------ stages
# Each stage: (params, out folder, input folders, cache) -> (outputs {name: relative path}, the equivalent
# panovocc command line (paths relative to the cache), a small summary dict).

def _synth(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..datasets.synth import SynthConfig, run_synth

    extra = {"house": True} if p.get("house") else {}
    s = run_synth(SynthConfig(out=out / "scene", seed=p["seed"], rooms=p["rooms"], frames=p["frames"], **extra))
    cmd = f"panovocc synth {_rel(out / 'scene', cache)} --seed {p['seed']} --frames {p['frames']}" + (
        " --house" if p.get("house") else f" --rooms {p['rooms']}")
    return {"scene": "scene"}, cmd, {k: s[k] for k in ("rooms", "objects", "frames", "path_m") if k in s}


def _gt(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..gt import GtConfig, run_gt

    if p["source"] == "mesh":
        scene = deps[0] / "scene"
        s = run_gt(GtConfig(scene=scene, out=out / "gt.npz"))
        return {"gt": "gt.npz"}, f"panovocc gt {_rel(scene, cache)} {_rel(out / 'gt.npz', cache)}", _plain(s)
    # ground truth lifted from sparse annotations (issue 13): gt --from-sequence SEQ --annotated every:K
    from ..gt_config import LiftParams  # type: ignore[attr-defined]

    seq = deps[0] / "seq"
    lift = LiftParams(annotated=f"every:{p['annotate_every']}")
    s = run_gt(GtConfig(scene=None, out=out / "gt.npz", from_sequence=seq, lift=lift,  # type: ignore[call-arg]
                        progress=False))
    (out / "gt.config.json").unlink(missing_ok=True)  # holds the temporary folder's paths
    return ({"gt": "gt.npz"}, f"panovocc gt --from-sequence {_rel(seq, cache)} {_rel(out / 'gt.npz', cache)} "
            f"--annotated every:{p['annotate_every']}", _plain(s))


def _render(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..rendering.render import RenderConfig, run_render

    scene = deps[0] / "scene"
    s = run_render(RenderConfig(scene=scene, out=out / "seq", width=p["width"], noise=p["noise"], seed=p["seed"],
                                threads=1, progress=False))
    cmd = (f"panovocc render {_rel(scene, cache)} {_rel(out / 'seq', cache)} --width {p['width']} "
           f"--noise {p['noise']} --seed {p['seed']}")
    return {"seq": "seq"}, cmd, _plain(s)


def _poses(p: dict, out: Path, deps: list[Path], cache: Path):
    """Poses other than the true ones, one per frame (``poses.txt``, NICE-SLAM form).

    ``source: drift``: the sequence's true poses with seeded odometry-style drift (geometry/drift.py).
    ``source: slam``: the SLAM front end's trajectory (``slam.run.run_slam_poses``: the ``poses.txt`` that
    ``map --poses slam`` writes, without building that map); it lives in the first frame's world, so the
    benchmark maps with these poses aligned to the reference (``--poses-align se3``), the paper's protocol.
    """
    from ..io.poses import read_poses, write_poses

    seq = deps[0] / "seq"
    if p["source"] == "slam":  # the front end alone (no map): the poses.txt map --poses slam writes, tested equal
        from ..slam.run import run_slam_poses  # type: ignore[import-not-found]

        s = run_slam_poses(seq, out / "slam")
        shutil.copyfile(out / "slam" / "poses.txt", out / "poses.txt")
        shutil.copyfile(out / "slam" / "slam.json", out / "slam.json")
        shutil.rmtree(out / "slam")
        keep = ("frames", "placed", "unplaced_frames", "track_ms_per_frame")
        return ({"poses": "poses.txt"}, f"panovocc map {_rel(seq, cache)} {_rel(out / 'slam', cache)} --poses slam "
                "--segmenter none", {k: v for k, v in _plain(s).items() if k in keep})
    from ..geometry.drift import drift_trajectory  # type: ignore[import-not-found]

    drifted = drift_trajectory(read_poses(seq / "poses.txt"), trans_m_per_sqrt_frame=p["trans_m_per_sqrt_frame"],
                               trans_m_per_m=p["trans_m_per_m"], rot_deg_per_frame=p["rot_deg_per_frame"],
                               seed=p["seed"])
    write_poses(out / "poses.txt", drifted)
    return ({"poses": "poses.txt"}, f"panovocc traj perturb {_rel(seq / 'poses.txt', cache)} "
            f"{_rel(out / 'poses.txt', cache)} --drift {p['trans_m_per_sqrt_frame']:g} --drift-per-m "
            f"{p['trans_m_per_m']:g} --rot-drift-deg {p['rot_deg_per_frame']:g} --seed {p['seed']}", {})


def _map(p: dict, out: Path, deps: list[Path], cache: Path):
    import dataclasses

    from ..mapping.config import MapConfig, SemanticParams
    from ..mapping.params import GeometryParams
    from ..mapping.pipeline import run_map
    from .methods import map_cli_flags

    o = p["options"]
    seq = deps[0] / "seq"
    poses = None
    pose_flag = ""
    align = "none"
    if o["poses"] in ("drift", "slam"):
        poses = deps[1] / "poses.txt"
        pose_flag = f" --poses {_rel(poses, cache)}"
        if o["poses"] == "slam":  # the estimated trajectory, aligned to the reference first (Umeyama SE(3))
            align = "se3"
            pose_flag += " --poses-align se3"
    sem = SemanticParams(segmenter=o["segmenter"], noise=float(o["noise"]), seed=p["seed"], use_gsc=o["use_gsc"])
    cfg = MapConfig(seq=str(seq), out=str(out / "map"), poses=None if poses is None else str(poses),
                    geometry=dataclasses.replace(GeometryParams(), kernel=o["kernel"]), semantic=sem)
    if align != "none":
        cfg = dataclasses.replace(cfg, poses_align=align)  # type: ignore[call-arg]
    flags = []
    if not o["rpu"]:  # the ablation's perturbation-and-correction schedule, corrections without RPU (issue 12)
        from ..mapping.ablation import AblationParams  # type: ignore[import-not-found]

        sch = p["schedule"]
        cfg = dataclasses.replace(cfg, ablation=AblationParams(  # type: ignore[call-arg]
            use_rpu=False, drift_rot_deg=sch["rot_deg"], drift_trans_m=sch["trans_m"], drift_seed=sch["seed"],
            correct_every=sch["every"]))
        flags = [f"--drift-rot-deg {sch['rot_deg']:g} --drift-trans-m {sch['trans_m']:g} --drift-seed {sch['seed']} "
                 f"--correct-every {sch['every']}"]
    s = run_map(cfg, progress=False)
    # keep what the tables read (the prediction, the resolved config, the poses); drop the delta store
    for name in ("deltas",):
        shutil.rmtree(out / "map" / name, ignore_errors=True)
    for name in ("memory.npz", "map.ply"):
        (out / "map" / name).unlink(missing_ok=True)
    cmd = " ".join(["panovocc map", _rel(seq, cache), _rel(out / "map", cache), *map_cli_flags(o), *flags,
                    f"--seed {p['seed']}"]) + pose_flag
    keep = ("frames", "occupied", "free", "classed", "empty_frames")
    return {"prediction": "map/prediction.npz"}, cmd, {k: s[k] for k in keep if k in s}


def _baseline(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..baselines.run import BaselineConfig, run_baseline  # type: ignore[attr-defined]

    seq = deps[0] / "seq"
    poses, align, pose_flag = None, "none", ""
    if p.get("poses") == "slam":  # the SLAM front end's trajectory, aligned as for map (Umeyama SE(3))
        poses, align = deps[1] / "poses.txt", "se3"
        pose_flag = f" --poses {_rel(poses, cache)} --poses-align se3"
    s = run_baseline(BaselineConfig(name=p["name"], seq=seq, out=out / "out", segmenter="simulated",  # type: ignore
                                    seed=p["seed"], poses=poses, poses_align=align, progress=False))
    for sub in ("streams", "frames"):  # per-view / per-frame grids: not read by the tables
        shutil.rmtree(out / "out" / sub, ignore_errors=True)
    cmd = (f"panovocc baselines run {p['name']} {_rel(seq, cache)} {_rel(out / 'out', cache)} --seed {p['seed']}"
           + pose_flag)
    keep = ("frames", "occupied", "classed", "views", "view_size")
    return {"prediction": "out/prediction.npz"}, cmd, {k: v for k, v in _plain(s).items() if k in keep}


def _eval(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..evaluation.metrics import count_pair
    from ..io.grid import read_grid

    pred_task, gt_task = deps
    pred_rel = json.loads((pred_task / TASK_FILE).read_text())["outputs"]["prediction"]
    pred, gt = pred_task / pred_rel, gt_task / "gt.npz"
    counts = count_pair(read_grid(pred), read_grid(gt))
    (out / "counts.json").write_text(json.dumps({m: counts_to_json(c) for m, c in counts.items()}, indent=2,
                                                sort_keys=True) + "\n", encoding="utf-8")
    cmd = f"panovocc eval {_rel(pred, cache)} {_rel(gt, cache)} --classes {p['classes']}"
    return {"counts": "counts.json"}, cmd, {}


def _coverage(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..evaluation.run import CoverageConfig, run_coverage

    seq, gt = deps[0] / "seq", deps[1] / "gt.npz"
    r = run_coverage(CoverageConfig(seq=seq, gt=gt, out_dir=out / "coverage", every=p["every"], progress=False))
    cmd = f"panovocc coverage {_rel(seq, cache)} {_rel(gt, cache)} --out {_rel(out / 'coverage', cache)}"
    if p["every"] != 1:
        cmd += f" --every {p['every']}"
    summary = {"frames": int(len(r["frame"])), "gt_occupied": int(r["total"]),
               "panoramic": [float(x) for x in r["panoramic"]], "perspective": [float(x) for x in r["perspective"]],
               "vfov_deg": float(r["vfov_deg"])}
    return {"csv": "coverage/coverage.csv", "png": "coverage/coverage.png"}, cmd, summary


def _show(p: dict, out: Path, deps: list[Path], cache: Path):
    from ..evaluation.run import ShowConfig, run_show

    grids = [deps[0] / "gt.npz"]
    for d in deps[1:]:
        grids.append(d / json.loads((d / TASK_FILE).read_text())["outputs"]["prediction"])
    run_show(ShowConfig(grids=grids, out_png=out / "qualitative.png", cut_top=p["cut_top"],
                        titles=list(p["titles"]), width_px=p["width_px"]))
    (out / "qualitative.config.json").unlink(missing_ok=True)  # holds the temporary folder's paths
    cmd = (f"panovocc show {' '.join(_rel(g, cache) for g in grids)} {_rel(out / 'qualitative.png', cache)} "
           f"--cut-top {p['cut_top']} --titles '{','.join(p['titles'])}' --width-px {p['width_px']}")
    return {"png": "qualitative.png"}, cmd, {}


STAGES = {"synth": _synth, "gt": _gt, "render": _render, "poses": _poses, "map": _map, "baseline": _baseline,
          "eval": _eval, "coverage": _coverage, "show": _show}


def _plain(s: Any) -> dict:
    """A run summary reduced to JSON-able scalars and short lists (paths as strings)."""
    if not isinstance(s, dict):
        return {}
    out = {}
    for k, v in s.items():
        if isinstance(v, (bool, int, float, str)) or v is None:
            out[k] = v
        elif isinstance(v, (list, tuple)) and len(v) <= 32 and all(isinstance(x, (int, float, str)) for x in v):
            out[k] = list(v)
    return out


# ------------------------------------------------------------------------------------ counts (JSON)
def counts_to_json(c) -> dict:
    """A :class:`~panovocc_cli.evaluation.metrics.Counts` as JSON (integers; per-class ``[tp, fp, fn]``)."""
    return {"tp": int(c.tp), "fp": int(c.fp), "fn": int(c.fn), "tn": int(c.tn), "pairs": int(c.pairs),
            "gt_names": list(c.gt_names), "classes": {k: [int(x) for x in v] for k, v in c.classes.items()}}


def counts_from_json(d: dict):
    """Inverse of :func:`counts_to_json`."""
    import numpy as np

    from ..evaluation.metrics import Counts

    return Counts(int(d["tp"]), int(d["fp"]), int(d["fn"]), int(d["tn"]),
                  {k: np.asarray(v, dtype=np.int64) for k, v in d["classes"].items()}, list(d["gt_names"]),
                  int(d["pairs"]))
