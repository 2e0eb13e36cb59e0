"""The evaluation stage's ``run_*`` functions: read inputs, call the maths, write outputs.

Each takes a config dataclass (the CLI builds it from its options) and is usable from Python::

    from panovocc_cli.evaluation.run import EvalConfig, run_eval
    results = run_eval(EvalConfig(pairs=[("pred.npz", "gt.npz")], classes="eval8"))
    print(results["pooled"]["freeocc"].miou)
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PanovoccError
from ..io.atomic import write_text
from ..io.grid import read_grid, write_grid
from .metrics import HEADLINE_MASK, MASK_LABELS, MASKS, Result, evaluate, resolve_classes
from .tables import counts_csv, write_tables


def _jsonable(x: Any) -> Any:
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def write_config(path: Path, cfg: Any) -> None:
    """Save a resolved config as JSON next to the outputs, so the run can be repeated."""
    write_text(path, json.dumps(_jsonable(asdict(cfg)), indent=2) + "\n")


# ----------------------------------------------------------------------------------------- eval
@dataclass
class EvalConfig:
    """Options of ``panovocc eval``.

    pairs : (prediction .npz, ground truth .npz) pairs, pooled by summing counts
    classes : class set for mIoU: eval8 | open4 | eval12 | all | comma list
    mask : headline mask of the JSON output: freeocc | observed (tables always show both)
    out_dir : folder for scores.csv/.md/.tex, counts.csv, scores.json, config.json (None: write nothing)
    """

    pairs: list[tuple[Path, Path]] = field(default_factory=list)
    classes: str = "eval8"
    mask: str = HEADLINE_MASK
    out_dir: Path | None = None


def read_pairs_csv(path: str | Path) -> list[tuple[Path, Path]]:
    """Pairs from a CSV: two columns (prediction, ground truth), optional header ``pred,gt``, ``#`` comments.

    Relative paths are resolved against the CSV's folder.
    """
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("pairs CSV not found", path)
    pairs = []
    with open(path, newline="", encoding="utf-8") as f:
        for n, row in enumerate(csv.reader(f), start=1):
            row = [c.strip() for c in row]
            if not row or not any(row) or row[0].startswith("#"):
                continue
            if len(row) < 2:
                raise PanovoccError(f"line {n}: expected two columns (prediction, ground truth)", path)
            if n == 1 and row[0].lower() in ("pred", "prediction") and row[1].lower() in ("gt", "ground_truth"):
                continue
            pairs.append(tuple(p if p.is_absolute() else path.parent / p for p in (Path(row[0]), Path(row[1]))))
    if not pairs:
        raise PanovoccError("no pairs listed (expected lines 'prediction.npz,ground_truth.npz')", path)
    return pairs  # type: ignore[return-value]


def run_eval(cfg: EvalConfig) -> dict[str, Any]:
    """Score the pairs (each, and pooled) under both masks; write tables when ``cfg.out_dir`` is set.

    Returns
    -------
    {"pooled": {mask: Result}, "pairs": [{mask: Result}, ...] (one per pair, in order)}
    """
    if cfg.mask not in MASKS:
        raise PanovoccError(f"unknown mask {cfg.mask!r} (expected {' or '.join(MASKS)})")
    if not cfg.pairs:
        raise PanovoccError("no pairs to score (give PRED GT, --pair or --pairs)")
    per_pair = []
    for pred_path, gt_path in cfg.pairs:
        pred, gt = read_grid(pred_path), read_grid(gt_path)
        try:
            res = evaluate([(pred, gt)], cfg.classes, {"pred": str(pred_path), "gt": str(gt_path),
                                                       "voxel_size": gt.voxel_size})
        except PanovoccError as e:
            raise PanovoccError(f"{pred_path} vs {gt_path}: {e}") from None
        per_pair.append(res)
    totals = {m: sum((r[m].counts for r in per_pair[1:]), per_pair[0][m].counts) for m in MASKS}
    names = resolve_classes(cfg.classes, totals[HEADLINE_MASK])  # 'all': every class any GT names
    info = {"pairs": [[str(p), str(g)] for p, g in cfg.pairs]}
    pooled = {m: Result(totals[m], m, names, dict(info)) for m in MASKS}
    out = {"pooled": pooled, "pairs": per_pair}
    if cfg.out_dir is not None:
        write_eval_outputs(out, cfg)
    return out


def row_names(cfg: EvalConfig) -> list[str]:
    """Row labels of the per-pair table rows: the prediction's file stem (with its folder when stems repeat)."""
    stems = [p.stem for p, _ in cfg.pairs]
    if len(set(stems)) < len(stems):
        stems = [f"{p.parent.name}/{p.stem}" for p, _ in cfg.pairs]
    return stems


def write_eval_outputs(out: dict[str, Any], cfg: EvalConfig) -> list[Path]:
    """scores.{csv,md,tex} (rows: each pair then pooled, both masks), counts.csv, scores.json, config.json."""
    d = Path(cfg.out_dir)  # type: ignore[arg-type]
    results, names = [], []
    if len(cfg.pairs) > 1:
        for name, res in zip(row_names(cfg), out["pairs"]):
            for m in MASKS:
                results.append(res[m])
                names.append(name)
    for m in MASKS:
        results.append(out["pooled"][m])
        names.append("pooled" if len(cfg.pairs) > 1 else row_names(cfg)[0])
    paths = write_tables(results, names, d, "scores")
    write_text(d / "counts.csv", counts_csv(results, names))
    write_text(d / "scores.json", json.dumps(eval_json(out, cfg.mask), indent=2) + "\n")
    write_config(d / "config.json", cfg)
    return paths + [d / "counts.csv", d / "scores.json", d / "config.json"]


def eval_json(out: dict[str, Any], mask: str) -> dict[str, Any]:
    """The ``--json`` object: the chosen mask's scores at top level, both masks under ``masks``, and per pair."""
    pooled = out["pooled"]
    obj = pooled[mask].to_dict()
    obj["headline_mask"] = HEADLINE_MASK
    obj["masks"] = {m: pooled[m].to_dict() for m in MASKS}
    obj["pairs"] = [{m: r[m].to_dict() for m in MASKS} for r in out["pairs"]] if len(out["pairs"]) > 1 else []
    return obj


def format_report(out: dict[str, Any]) -> str:
    """Readable table of the pooled scores, both masks side by side (FreeOcc labelled headline)."""
    f, o = out["pooled"]["freeocc"], out["pooled"]["observed"]

    def cell(x: float) -> str:
        return "n/a" if math.isnan(x) else f"{x:.2f}"

    n = len(out["pairs"])
    lines = [f"scores in percent, {n} pair{'s' if n != 1 else ''} pooled" if n > 1 else "scores in percent",
             f"classes: {', '.join(f.classes)}  ({len(f.present)} present in the ground truth)",
             f"{'':24}{MASK_LABELS['freeocc']:>20}{MASK_LABELS['observed']:>16}",
             f"{'IoU (occupancy)':24}{cell(f.iou):>20}{cell(o.iou):>16}",
             f"{'mIoU':24}{cell(f.miou):>20}{cell(o.miou):>16}"]
    present = set(f.present)
    for c in f.classes:
        if c in present:
            lines.append(f"  {c:22}{cell(f.class_iou(c)):>20}{cell(o.class_iou(c)):>16}")
        else:
            lines.append(f"  {c:22}{'absent from GT':>20}{'':>16}")
    lines.append(f"scored voxels: {f.counts.scored} (FreeOcc), {o.counts.scored} (observed); "
                 f"occupied TP {f.counts.tp} FP {f.counts.fp} FN {f.counts.fn}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------- coverage
@dataclass
class CoverageConfig:
    """Options of ``panovocc coverage``.

    seq : sequence folder (ERP); gt : ground-truth grid .npz; out_dir : output folder
    hfov_deg : perspective camera's horizontal field of view, degrees
    vfov_deg : vertical field of view, degrees (None: from ``aspect``)
    aspect : perspective image width / height when vfov_deg is None (Replica's 1200 / 680)
    every : use every K-th frame (the last frame is always used)
    tol_m : metres; a depth point this close to a voxel face also observes the voxel across it
    """

    seq: Path
    gt: Path
    out_dir: Path
    hfov_deg: float = 90.0
    vfov_deg: float | None = None
    aspect: float = 1200.0 / 680.0
    every: int = 1
    tol_m: float = 0.01
    progress: bool = True


def run_coverage(cfg: CoverageConfig) -> dict[str, np.ndarray]:
    """Cumulative coverage frame by frame; writes coverage.csv, coverage.png, config.json into ``out_dir``.

    Returns
    -------
    {"frame": (n,) int64, "panoramic": (n,) float64, "perspective": (n,) float64} fractions in [0, 1]
    """
    from tqdm import tqdm

    from ..io.sequence import Sequence
    from .coverage import CoverageTracker, frame_schedule, vertical_fov
    from .show import plot_coverage

    seq = Sequence(cfg.seq)
    if seq.meta.camera != "erp":
        raise PanovoccError("coverage needs a panoramic (ERP) sequence; this one is pinhole", cfg.seq)
    gt = read_grid(cfg.gt)
    if not 0 < cfg.hfov_deg < 180 or (cfg.vfov_deg is not None and not 0 < cfg.vfov_deg < 180):
        raise PanovoccError("fields of view must be in (0, 180) degrees")
    if not cfg.aspect > 0:
        raise PanovoccError(f"--aspect must be positive, got {cfg.aspect}")
    hfov = math.radians(cfg.hfov_deg)
    vfov = math.radians(cfg.vfov_deg) if cfg.vfov_deg is not None else vertical_fov(hfov, cfg.aspect)
    tracker = CoverageTracker(gt, seq.meta.width, seq.meta.height, hfov, vfov, cfg.tol_m)
    frames = frame_schedule(len(seq), cfg.every)
    pano, persp = [], []
    for i in tqdm(frames, desc="coverage", unit="frame", disable=not cfg.progress):
        c = tracker.add(seq.depth(i), seq.poses[i])
        pano.append(c["panoramic"])
        persp.append(c["perspective"])
    res = {"frame": np.asarray(frames, dtype=np.int64), "panoramic": np.asarray(pano),
           "perspective": np.asarray(persp)}
    out = Path(cfg.out_dir)
    lines = ["frame,panoramic,perspective"] + [f"{f},{a:.6f},{b:.6f}" for f, a, b in zip(frames, pano, persp)]
    write_text(out / "coverage.csv", "\n".join(lines) + "\n")
    plot_coverage(res["frame"], res["panoramic"], res["perspective"], out / "coverage.png",
                  title=f"{Path(cfg.seq).name}: {tracker.total} GT occupied voxels", hfov_deg=cfg.hfov_deg)
    write_config(out / "config.json", cfg)
    res["vfov_deg"] = np.float64(math.degrees(vfov))
    res["total"] = np.int64(tracker.total)
    return res


# ----------------------------------------------------------------------------------------- show
@dataclass
class ShowConfig:
    """Options of ``panovocc show``: grids drawn side by side in one common box."""

    grids: list[Path]
    out_png: Path
    cut_top: int = 0
    titles: list[str] | None = None
    width_px: int = 1600


def run_show(cfg: ShowConfig) -> tuple[int, int]:
    """Render the grids into one PNG; returns its (height, width) in pixels."""
    from .show import render_panels, save_panels

    if not cfg.grids:
        raise PanovoccError("no grids to show")
    if cfg.titles is not None and len(cfg.titles) != len(cfg.grids):
        raise PanovoccError(f"{len(cfg.titles)} titles for {len(cfg.grids)} grids")
    if cfg.width_px < 64:
        raise PanovoccError(f"--width-px must be >= 64, got {cfg.width_px}")
    if cfg.out_png.suffix.lower() != ".png":
        raise PanovoccError("output must be a .png file", cfg.out_png)
    grids = [read_grid(p) for p in cfg.grids]
    images, legend = render_panels(grids, cfg.cut_top, panel_px=max(64, cfg.width_px // len(grids)))
    return save_panels(images, legend, cfg.out_png, cfg.titles, cfg.width_px)


# -------------------------------------------------------------------------------------- convert
@dataclass
class ConvertReplicaOccConfig:
    """Options of ``panovocc convert replicaocc``."""

    pkl: Path
    out_npz: Path
    class_names: str | None = None
    voxel_size: float | None = None
    tol_m: float | None = None
    allow_shift: bool = False


def run_convert_replicaocc(cfg: ConvertReplicaOccConfig):
    """ReplicaOcc ``.pkl`` -> grid ``.npz``; returns (Grid, shift (3,) metres)."""
    from .replicaocc import parse_class_names, read_replicaocc

    names = parse_class_names(cfg.class_names) if cfg.class_names else None
    grid, shift = read_replicaocc(cfg.pkl, names, cfg.voxel_size, cfg.tol_m, cfg.allow_shift)
    write_grid(cfg.out_npz, grid)
    return grid, shift


def run_convert_to_replicaocc(grid_path: Path, out_pkl: Path):
    """Grid ``.npz`` -> ReplicaOcc ``.pkl``; returns the Grid."""
    from .replicaocc import write_replicaocc

    grid = read_grid(grid_path)
    write_replicaocc(out_pkl, grid)
    return grid
