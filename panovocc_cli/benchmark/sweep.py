"""A sweep: scenes x methods x variants as a graph of :class:`~.tasks.Task`, and where each table cell
comes from.

Per scene: ``synth`` -> ``render`` -> ground truth (``gt``: from the mesh, or lifted from the rendered
sequence); per (scene, method): the prediction (``map`` or ``baseline``, after a ``poses`` task for a
drifting trajectory) -> ``eval`` (voxel counts against the ground truth). Per scene a ``coverage`` task;
per split one ``show`` task (the first scene: ground truth beside each main and ablation method).
Methods and splits this build cannot run are recorded with the reason and get no task.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .methods import DRIFT, RPU_SCHEDULE, Method
from .splits import SCALE_SPECS, SceneSpec, Split
from .tasks import Task, code_fingerprint

SHOW_CUT_TOP = 5  # voxel layers removed from the top of the common box, to look into the rooms
SHOW_WIDTH_PX = 1800
ABLATION_SPLIT = "pan-replica-synth"  # the component ablation's split (the paper's Table: Pan-Replica)
DRIFT_SEED_OFFSET = 7919  # the drifting trajectory's seed: scene seed + this (its own stream)


@dataclass
class Sweep:
    """The graph and its bookkeeping.

    tasks : every task, inputs first; evals : (split, method, scene) -> eval task
    coverage : (split, scene) -> coverage task; shows : split -> (show task, titles)
    unavailable : ("split", name) or ("method", name) -> reason
    """

    scale: str
    splits: list[Split]
    methods: list[Method]
    scenes: dict[str, list[SceneSpec]] = field(default_factory=dict)
    tasks: list[Task] = field(default_factory=list)
    evals: dict[tuple[str, str, str], Task] = field(default_factory=dict)
    coverage: dict[tuple[str, str], Task] = field(default_factory=dict)
    shows: dict[str, Task] = field(default_factory=dict)
    unavailable: dict[tuple[str, str], str] = field(default_factory=dict)


def _label(kind: str, split: Split, scene: SceneSpec, what: str = "") -> str:
    return " ".join(x for x in (kind, what, f"{split.name}/{scene.name}") if x)


def build_sweep(splits: list[Split], methods: list[Method], scale: str) -> Sweep:
    """The task graph of ``methods`` on the scenes of ``splits`` at ``scale``."""
    code = code_fingerprint()
    sw = Sweep(scale, list(splits), list(methods))
    spec = SCALE_SPECS[scale]
    for m in methods:
        why = m.unavailable()
        if why:
            sw.unavailable[("method", m.name)] = why
    for split in splits:
        why = split.unavailable()
        if why:
            sw.unavailable[("split", split.name)] = why
            continue
        scenes = split.scenes(scale)
        sw.scenes[split.name] = scenes
        for k, sc in enumerate(scenes):
            synth = Task("synth", {"seed": sc.seed, "rooms": sc.rooms, "frames": sc.frames, "house": sc.house},
                         (), _label("synth", split, sc), code)
            render = Task("render", {"width": sc.width, "noise": sc.noise, "seed": sc.seed}, (synth,),
                          _label("render", split, sc), code)
            if split.gt == "mesh":
                gt = Task("gt", {"source": "mesh"}, (synth,), _label("gt", split, sc), code)
            else:
                gt = Task("gt", {"source": "lifted", "annotate_every": spec.annotate_every}, (render,),
                          _label("gt", split, sc), code)
            preds: dict[str, Task] = {}
            for m in methods:
                if ("method", m.name) in sw.unavailable:
                    continue
                if set(m.groups) == {"ablation"} and split.name != ABLATION_SPLIT:
                    continue  # the component ablation is on pan-replica-synth only, as the paper's
                pred = _prediction(m, split, sc, render, code)
                if pred is None:
                    continue
                preds[m.name] = pred
                sw.evals[(split.name, m.name, sc.name)] = Task(
                    "eval", {"classes": split.classes}, (pred, gt), _label("eval", split, sc, m.name), code)
            sw.coverage[(split.name, sc.name)] = Task("coverage", {"every": spec.coverage_every}, (render, gt),
                                                      _label("coverage", split, sc), code)
            if k == 0:
                shown = [m for m in methods if m.name in preds and {"main", "ablation"} & set(m.groups)]
                titles = ["ground truth"] + [m.label if len(m.label) <= 16 else m.name for m in shown]
                sw.shows[split.name] = Task(
                    "show", {"cut_top": SHOW_CUT_TOP, "titles": titles, "width_px": SHOW_WIDTH_PX},
                    (gt, *[preds[m.name] for m in shown]), _label("show", split, sc), code)
    from .tasks import topological

    sw.tasks = topological([*sw.evals.values(), *sw.coverage.values(), *sw.shows.values()])
    return sw


def _poses_task(source: str, split: Split, sc: SceneSpec, render: Task, code: str) -> Task:
    """The ``poses`` task of scene ``sc``: ``slam`` (the front end's trajectory) or ``drift`` (seeded drift);
    every method of the scene that uses those poses depends on this one task."""
    params = {"source": "slam"} if source == "slam" else {"source": "drift", **DRIFT,
                                                           "seed": sc.seed + DRIFT_SEED_OFFSET}
    return Task("poses", params, (render,), _label("poses", split, sc, source), code)


def _prediction(m: Method, split: Split, sc: SceneSpec, render: Task, code: str) -> Task | None:
    """The task that makes method ``m``'s prediction on scene ``sc``."""
    if m.runner == "baseline":  # on the split's poses, as PanOVOcc's row (SLAM: the same aligned trajectory)
        params = {"name": m.options["name"], "seed": sc.seed}
        deps: tuple[Task, ...] = (render,)
        if split.poses == "slam":
            params["poses"] = "slam"
            deps = (render, _poses_task("slam", split, sc, render, code))
        return Task("baseline", params, deps, _label("baseline", split, sc, m.name), code)
    opts = m.map_options()
    poses = split.poses if opts["poses"] == "default" else opts["poses"]
    opts = {**opts, "poses": poses}
    deps = (render, _poses_task(poses, split, sc, render, code)) if poses in ("drift", "slam") else (render,)
    params = {"options": opts, "seed": sc.seed}
    if not opts["rpu"]:
        params["schedule"] = {**RPU_SCHEDULE, "seed": sc.seed + DRIFT_SEED_OFFSET}
    return Task("map", params, deps, _label("map", split, sc, m.name), code)
