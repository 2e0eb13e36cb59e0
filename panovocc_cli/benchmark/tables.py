"""The benchmark's tables, shaped like the paper's, from a finished sweep: header, rows, provenance.

Pure: reads no file, prints nothing. Scores are pooled over a split's scenes (voxel counts summed, then
divided: the FreeOcc protocol, evaluation/metrics.py), in percent with two decimals; mIoU is FreeOcc's
(mean over every eval8 class). Rows measured here say ``measured``; the paper's rows say ``reported``
(they are on the real datasets, not these synthetic splits); a method or split this build lacks says
``not available in this build (needs ...)`` with ``-`` in every number cell; a task that failed says so.
Nothing in a table depends on the time or on which tasks were cached, so a rerun gives the same bytes.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Callable

from ..classes import EVAL8, OPEN4
from . import reported
from .methods import RPU_SCHEDULE, Method
from .sweep import ABLATION_SPLIT, Sweep

NA = "-"
MEASURED = "measured"


@dataclass
class Table:
    """One table: ``stem`` names its files; ``rows`` align with ``header``; ``provenance`` has one entry per
    row (data, command, config hash) and ``notes`` are lines shown under it."""

    stem: str
    title: str
    header: list[str]
    rows: list[list[str]] = field(default_factory=list)
    provenance: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def fmt(x: float | None) -> str:
    return NA if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"


class Scores:
    """Pooled scores of (split, method) from the eval tasks' counts.

    ``counts_of(task) -> {mask: Counts} | None`` (None: the task failed) is supplied by the caller, which
    reads the cache.
    """

    def __init__(self, sweep: Sweep, counts_of: Callable, errors: dict[str, str]):
        self.sweep, self.counts_of, self.errors = sweep, counts_of, errors

    def pooled(self, split: str, method: str, classes=EVAL8):
        """(Result under the FreeOcc mask, None) or (None, reason)."""
        from ..evaluation.metrics import Result

        why = self.sweep.unavailable.get(("split", split)) or self.sweep.unavailable.get(("method", method))
        if why:
            return None, why
        tasks = [self.sweep.evals[(split, method, sc.name)] for sc in self.sweep.scenes.get(split, [])
                 if (split, method, sc.name) in self.sweep.evals]
        if not tasks:
            return None, "not in this sweep"
        total = None
        for t in tasks:
            c = self.counts_of(t)
            if c is None:
                return None, f"failed: {self.errors.get(t.key, 'a task failed')}"
            total = c["freeocc"] if total is None else total + c["freeocc"]
        return Result(total, "freeocc", list(classes), {}), None

    def config_hash(self, split: str, methods: list[str]) -> str:
        """12 hex digits naming every eval task behind a row (hence every config and input behind it)."""
        keys = sorted(t.key for (s, m, _), t in self.sweep.evals.items() if s == split and m in methods)
        return hashlib.sha256("\n".join(keys).encode()).hexdigest()[:12] if keys else NA


def _data(sweep: Sweep, split: str) -> str:
    scenes = sweep.scenes.get(split, [])
    if not scenes:
        return f"{split} (not run)"
    seeds = ",".join(str(s.seed) for s in scenes)
    sc = scenes[0]
    return (f"{split} scale {sweep.scale}: {len(scenes)} scene(s), synth seeds {seeds}, {sc.frames} frames at "
            f"{sc.width}x{sc.width // 2}, render noise {sc.noise}")


def _command(sweep: Sweep, split: str, methods: str) -> str:
    return f"panovocc reproduce --scale {sweep.scale} --splits {split} --methods {methods}"


def main_table(sweep: Sweep, scores: Scores, split: str) -> Table:
    """Table 1 for one split: IoU, mIoU (eval8), per-class IoU (+ open4 on the Holo-style split)."""
    holo = split == "pan-holo-synth"
    classes = list(EVAL8) + (list(OPEN4) if holo else [])
    header = ["method", "source", "IoU", "mIoU"] + classes
    t = Table(f"main_{split}", f"Main comparison on {split}", header)
    split_missing = sweep.unavailable.get(("split", split))
    if split_missing:
        t.notes.append(f"{split}: split {split_missing}; its measured rows are empty until then.")
    for m in [m for m in sweep.methods if "main" in m.groups]:
        res, why = scores.pooled(split, m.name, EVAL8)
        if split_missing:
            why = "split not available in this build (see notes)"
        if res is None:
            t.rows.append([m.label, why] + [NA] * (2 + len(classes)))
        else:
            cells = [fmt(res.iou), fmt(res.miou)]
            present = set(res.present) | set(_present(res, OPEN4))
            cells += [fmt(res.class_iou(c)) if c in present else NA for c in classes]
            t.rows.append([m.label, MEASURED] + cells)
        t.provenance.append({"row": m.label, "data": _data(sweep, split), "command": _command(sweep, split, m.name),
                             "config": scores.config_hash(split, [m.name])})
    table = reported.MAIN_HOLO if holo else reported.MAIN_REPLICA
    label = reported.TABLE_LABELS[f"main:{split}"]
    paper = "Pan-Holo360D" if holo else "Pan-Replica"
    for name, vals in table.items():
        t.rows.append([name, f"reported ({paper}, paper {label})"] + [fmt(v) for v in vals])
        t.provenance.append({"row": name, "data": f"paper: {paper}", "command": "-", "config": "-"})
    t.notes.append("mIoU: FreeOcc's rule, the mean over the eight eval8 classes (a class absent from the ground "
                   "truth counts 0); a class cell is '-' when the split's ground truth lacks the class.")
    if holo:
        t.notes.append("open4 classes (curtain, door, tv, lighting): per-class IoU, not in mIoU (as the paper).")
    sp = next((x for x in sweep.splits if x.name == split), None)
    if sp is not None and sp.poses == "slam":
        t.notes.append("poses: every measured row uses the SLAM front end's trajectory of the scene, aligned to the "
                       "true one (Umeyama SE(3)), as the paper aligns each baseline's SLAM trajectory.")
    t.notes.append("reported rows are the paper's numbers on the real benchmark, shown for reference only.")
    return t


def _present(res, names) -> list[str]:
    """Names of ``names`` with scored ground-truth voxels in a Result (which may average another set)."""
    return [n for n in names if res.gt_voxels(n) > 0]


def per_scene_table(sweep: Sweep, counts_of: Callable, split: str) -> Table:
    """Every (method, scene) cell of a split: IoU and mIoU per scene (the main table pools them)."""
    from ..evaluation.metrics import Result

    t = Table(f"per_scene_{split}", f"Per-scene scores on {split}", ["method", "scene", "IoU", "mIoU"])
    for m in sweep.methods:
        for sc in sweep.scenes.get(split, []):
            task = sweep.evals.get((split, m.name, sc.name))
            if task is None:
                continue
            c = counts_of(task)
            if c is None:
                t.rows.append([m.name, sc.name, NA, NA])
            else:
                r = Result(c["freeocc"], "freeocc", list(EVAL8), {})
                t.rows.append([m.name, sc.name, fmt(r.iou), fmt(r.miou)])
            t.provenance.append({"row": f"{m.name} {sc.name}", "data": f"{split}/{sc.name} (seed {sc.seed})",
                                 "command": _command(sweep, split, m.name), "config": task.key[:12]})
    return t


def ablation_table(sweep: Sweep, scores: Scores, split: str = ABLATION_SPLIT) -> Table:
    """Table 2: the component ablation (w/o PSVF, w/o GSC, w/o RPU, full model)."""
    header = ["variant", "source", "PSVF", "GSC", "RPU", "IoU", "mIoU"]
    t = Table("ablation", f"Component ablation on {split}", header)
    order = [m for m in sweep.methods if "ablation" in m.groups and m.name != "panovocc"]
    order += [m for m in sweep.methods if m.name == "panovocc"]
    for m in order:
        label = "Full model" if m.name == "panovocc" else m.label
        marks = ["yes" if c in m.components else "no" for c in ("PSVF", "GSC", "RPU")]
        res, why = scores.pooled(split, m.name)
        if res is None:
            t.rows.append([label, why] + marks + [NA, NA])
        else:
            t.rows.append([label, MEASURED] + marks + [fmt(res.iou), fmt(res.miou)])
        t.provenance.append({"row": label, "data": _data(sweep, split), "command": _command(sweep, split, m.name),
                             "config": scores.config_hash(split, [m.name])})
    comp = {"w/o PSVF": ("no", "yes", "yes"), "w/o GSC": ("yes", "no", "yes"), "w/o RPU": ("yes", "yes", "no"),
            "Full model": ("yes", "yes", "yes")}
    for name, (iou, miou) in reported.ABLATION.items():
        t.rows.append([name, f"reported (Pan-Replica, paper {reported.TABLE_LABELS['ablation']})", *comp[name],
                       fmt(iou), fmt(miou)])
        t.provenance.append({"row": name, "data": "paper: Pan-Replica", "command": "-", "config": "-"})
    sch = RPU_SCHEDULE
    t.notes.append(f"w/o RPU: every frame is integrated under a drifting pose (seeded random walk, {sch['rot_deg']:g} "
                   f"deg per frame and {sch['trans_m']:g} m per square-root frame) and the true poses of each block "
                   f"of {sch['every']} frames arrive as corrections; without the reversible update the corrected "
                   "frames are added on top of the stale contributions (map --no-rpu --drift-*). With it the "
                   "corrected map equals the true-pose map exactly, so the full model's row is PanOVOcc's.")
    return t


def upstream_table(sweep: Sweep, scores: Scores) -> Table:
    """Table 3: upstream modules (poses: true / SLAM / drifting; segmenter variants), IoU and mIoU per split."""
    splits = ["pan-replica-synth", "pan-holo-synth"]
    header = ["variant", "source"] + [f"{s} {k}" for s in splits for k in ("IoU", "mIoU")]
    t = Table("upstream", "Upstream modules", header)
    rows = [m for m in sweep.methods if "upstream" in m.groups]
    for m in rows:
        label = "default (split's poses, simulated segmenter)" if m.name == "panovocc" else m.label
        cells, ran, notes = [], [], []
        for s in splits:
            res, why = scores.pooled(s, m.name)
            if res is None:
                cells += [NA, NA]
                in_sweep = any(x.name == s for x in sweep.splits)
                if in_sweep and ("split", s) not in sweep.unavailable:  # a missing split is said once, below
                    notes.append(f"{s}: {why}")
            else:
                cells += [fmt(res.iou), fmt(res.miou)]
                ran.append(s)
        if ("method", m.name) in sweep.unavailable:
            notes = [sweep.unavailable[("method", m.name)]]
        source = "; ".join(([f"{MEASURED} ({', '.join(ran)})"] if ran else []) + notes) or NA
        t.rows.append([label, source] + cells)
        t.provenance.append({"row": label, "data": "; ".join(_data(sweep, s) for s in splits),
                             "command": _command(sweep, ",".join(splits), m.name),
                             "config": "/".join(scores.config_hash(s, [m.name]) for s in splits)})
    for name, vals in reported.UPSTREAM.items():
        t.rows.append([name, f"reported (Pan-Replica / Pan-Holo360D, paper {reported.TABLE_LABELS['upstream']})"]
                      + [fmt(v) for v in vals])
        t.provenance.append({"row": name, "data": "paper", "command": "-", "config": "-"})
    for s in splits:
        why = sweep.unavailable.get(("split", s))
        if why:
            t.notes.append(f"{s}: split {why}.")
    t.notes.append("default = the split's own poses (true on pan-replica-synth, SLAM on pan-holo-synth) and the "
                   "simulated segmenter at noise 1; the paper's default row uses ODGS-SLAM and OOOPS.")
    return t


def coverage_table(sweep: Sweep, summaries: dict) -> Table:
    """Table 4: coverage of the ground truth's occupied voxels at the last frame, panoramic vs perspective,
    and the mean over the trajectory (the area under the paper's Fig. 5 curves).

    ``summaries`` : (split, scene) -> the coverage task's summary (None: failed).
    """
    header = ["split", "scene", "frames", "GT occupied", "panoramic %", "perspective %", "pano mean %",
              "persp mean %"]
    t = Table("coverage", "Coverage: panoramic vs perspective along the same trajectory", header)
    for (split, scene), task in sweep.coverage.items():
        s = summaries.get((split, scene))
        if s is None:
            t.rows.append([split, scene] + [NA] * 6)
        else:
            pano, persp = s["panoramic"], s["perspective"]
            t.rows.append([split, scene, str(s["frames"]), str(s["gt_occupied"]), fmt(100 * pano[-1]),
                           fmt(100 * persp[-1]), fmt(100 * sum(pano) / len(pano)), fmt(100 * sum(persp) / len(persp))])
        t.provenance.append({"row": f"{split}/{scene}", "data": f"{split}/{scene}",
                             "command": _command(sweep, split, "panovocc"), "config": task.key[:12]})
    t.notes.append("perspective: a 90 degree horizontal field of view looking along each panorama's forward "
                   "direction (panovocc coverage defaults); coverage counts ground-truth occupied voxels seen.")
    return t
