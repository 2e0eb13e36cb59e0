"""The evaluation stage's ``run_*`` functions: read inputs, call the maths, write outputs (``eval``,
``coverage``, ``show``, the ReplicaOcc conversions, and ``segeval``: a segmenter's own per-frame 2D mIoU, whose
per-frame scores are :mod:`panovocc_cli.semantics.metrics2d`'s).

Each takes a config dataclass (the CLI builds it from its options) and is usable from Python::

    from panovocc_cli.evaluation.run import EvalConfig, run_eval
    results = run_eval(EvalConfig(pairs=[("pred.npz", "gt.npz")], classes="eval8"))
    print(results["pooled"]["freeocc"].miou)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..config import validate_config
from ..config import COVERAGE_TOL_M, DEFAULT_SEED, DEFAULT_VOXEL_SIZE, MAX_PICTURE_PX, MAX_SEED, MAX_VOXEL_SIZE, option
from ..errors import PanovoccError
from ..grid import EMPTY, UNKNOWN
from ..io.atomic import check_output, output_file, output_folder, write_text
from ..io.grid import read_grid, write_grid
from ..io.runconfig import check_file_output, write_run_config
from ..io.tables import write_csv
from ..io.tables import write_tables as write_table_files
from .metrics import HEADLINE_MASK, MASK_LABELS, MASKS, Result, evaluate, resolve_classes
from .tables import counts_rows, table_rows


def write_config(path: Path, cfg: Any) -> None:
    """Save a resolved config as JSON next to the outputs, so the run can be repeated (io/runconfig.py)."""
    write_run_config(path, cfg)


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
    classes: str = option("eval8", help="Class set for mIoU: eval8 | open4 | eval12 | all | comma list (a,b,c).")
    mask: str = option(HEADLINE_MASK, choices=MASKS,
                       help="Mask for the --json top level: freeocc (headline) | observed.")
    out_dir: Path | None = option(None, flag="--out",
                                  help="Folder for scores.csv/.md/.tex, counts.csv, scores.json, config.json.")
    overwrite: bool = option(False, help="Replace a previous eval output in --out (never any other folder).")


def run_eval(cfg: EvalConfig) -> dict[str, Any]:
    """Score the pairs (each, and pooled) under both masks; write tables when ``cfg.out_dir`` is set.

    Returns
    -------
    {"pooled": {mask: Result}, "pairs": [{mask: Result}, ...] (one per pair, in order)}
    """
    cfg = validate_config(cfg)
    if not cfg.pairs:
        raise PanovoccError("no pairs to score (give PRED GT, --pair or --pairs)")
    if cfg.out_dir is not None:
        check_output(cfg.out_dir, "eval", cfg.overwrite, inputs=[p for pair in cfg.pairs for p in pair])
    per_pair = []
    for pred_path, gt_path in cfg.pairs:
        pred, gt = read_grid(pred_path), read_grid(gt_path)
        if not np.any((gt.labels != EMPTY) & (gt.labels != UNKNOWN)):
            raise PanovoccError("the ground truth has no occupied voxel (every label is 0 or 255): nothing to score",
                                gt_path)
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


def write_score_tables(results: Sequence[Result], names: Sequence[str], out_dir: str | Path,
                       stem: str = "scores") -> list[Path]:
    """Write ``<stem>.csv``, ``<stem>.md`` and ``<stem>.tex`` (one row per Result) into ``out_dir``."""
    header, rows = table_rows(results, names)
    return write_table_files(header, rows, out_dir, stem)


def write_eval_outputs(out: dict[str, Any], cfg: EvalConfig) -> list[Path]:
    """scores.{csv,md,tex} (rows: each pair then pooled, both masks), counts.csv, scores.json, config.json.

    A folder this creates is removed again if writing fails (nothing half-done is left).
    """
    with output_folder(cfg.out_dir) as d:  # type: ignore[arg-type]
        return _write_eval_files(out, cfg, d)


def _write_eval_files(out: dict[str, Any], cfg: EvalConfig, d: Path) -> list[Path]:
    results, names = [], []
    if len(cfg.pairs) > 1:
        for name, res in zip(row_names(cfg), out["pairs"]):
            for m in MASKS:
                results.append(res[m])
                names.append(name)
    for m in MASKS:
        results.append(out["pooled"][m])
        names.append("pooled" if len(cfg.pairs) > 1 else row_names(cfg)[0])
    paths = write_score_tables(results, names, d, "scores")
    write_csv(d / "counts.csv", *counts_rows(results, names))
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
    if f.miou_rules_differ or o.miou_rules_differ:
        lines.append(f"{'mIoU (present only)':24}{cell(f.miou_present):>20}{cell(o.miou_present):>16}")
        lines.append(f"  (mIoU is FreeOcc's: the mean over all {len(f.classes)} classes, an absent class "
                     f"scoring 0; 'present only' averages the {len(f.present)} in the ground truth)")
    present = set(f.present)
    for c in f.classes:
        if c in present:
            lines.append(f"  {c:22}{cell(f.class_iou(c)):>20}{cell(o.class_iou(c)):>16}")
        else:
            lines.append(f"  {c:22}{'absent from GT (0)':>20}{'':>16}")
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

    seq: Path = option(argument=True, metavar="SEQ",
                       help="Panoramic (ERP) sequence folder: depth/ and poses.txt are used.")
    gt: Path = option(argument=True, metavar="GT",
                      help="Ground-truth grid .npz (its occupied voxels are the denominator).")
    out_dir: Path = option(flag="--out", help="Output folder for coverage.csv, coverage.png, config.json.")
    hfov_deg: float = option(90.0, flag="--fov-deg", min=0, min_open=True, max=179,
                             help="Perspective camera horizontal field of view, degrees.")
    vfov_deg: float | None = option(None, min=0, min_open=True, max=179,
                                    help="Perspective vertical field of view, degrees (default: from --aspect).")
    aspect: float = option(1200.0 / 680.0, min=0, min_open=True,
                           help="Perspective image width/height, used when --vfov-deg is not given "
                                "(default: Replica's 1200x680).")
    every: int = option(1, min=1, help="Use every K-th frame (the last frame is always used).")
    tol_m: float = option(COVERAGE_TOL_M, min=0, help="Metres: a depth point this close to a voxel face also "
                                                      "observes the voxel across it.")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous coverage output in --out (never any other folder).")


def run_coverage(cfg: CoverageConfig) -> dict[str, np.ndarray]:
    """Cumulative coverage frame by frame; writes coverage.csv, coverage.png, config.json into ``out_dir``.

    Returns
    -------
    {"frame": (n,) int64, "panoramic": (n,) float64, "perspective": (n,) float64} fractions in [0, 1]
    """
    from tqdm import tqdm

    from ..io.coverage import write_coverage_csv
    from ..io.sequence import Sequence
    from .coverage import CoverageTracker, frame_schedule, vertical_fov
    from ..io.figures import write_png
    from .show import coverage_figure

    cfg = validate_config(cfg)  # fields of view in (0, 179], aspect > 0, every >= 1: declared above
    check_output(cfg.out_dir, "coverage", cfg.overwrite, inputs=(cfg.seq, cfg.gt))
    seq = Sequence(cfg.seq)
    if seq.meta.camera != "erp":
        raise PanovoccError("coverage needs a panoramic (ERP) sequence; this one is pinhole", cfg.seq)
    seq.check_files(("depth",))  # every depth frame present and whole before any work
    gt = read_grid(cfg.gt)
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
    with output_folder(cfg.out_dir) as out:  # removed again if writing fails
        write_coverage_csv(out / "coverage.csv", res["frame"], res["panoramic"], res["perspective"])
        write_png(coverage_figure(res["frame"], res["panoramic"], res["perspective"],
                                  title=f"{Path(cfg.seq).name}: {tracker.total} GT occupied voxels",
                                  hfov_deg=cfg.hfov_deg), out / "coverage.png")
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
    cut_top: int = option(0, min=0, help="Remove the top K voxel layers (to look into rooms).")
    titles: list[str] | None = option(None, cli_type=str, parse=lambda s: [t.strip() for t in s.split(",")],
                                      help="Comma-separated panel titles, one per grid.")
    width_px: int = option(1600, min=64, max=MAX_PICTURE_PX, help="PNG width in pixels.")
    overwrite: bool = option(False, help="Replace an existing OUT.png (never an input).")


def run_show(cfg: ShowConfig) -> tuple[int, int]:
    """Render the grids into one PNG; returns its (height, width) in pixels."""
    from ..io.figures import write_png
    from .show import panels_figure, render_panels

    cfg = validate_config(cfg)
    if not cfg.grids:
        raise PanovoccError("no grids to show")
    if cfg.titles is not None and len(cfg.titles) != len(cfg.grids):
        raise PanovoccError(f"{len(cfg.titles)} titles for {len(cfg.grids)} grids")
    config_path = check_file_output(cfg.out_png, "picture", cfg.overwrite, inputs=cfg.grids)
    if cfg.out_png.suffix.lower() != ".png":
        raise PanovoccError("output must be a .png file", cfg.out_png)
    grids = [read_grid(p) for p in cfg.grids]
    images, legend = render_panels(grids, cfg.cut_top, panel_px=max(64, cfg.width_px // len(grids)))
    fig, size = panels_figure(images, legend, cfg.titles, cfg.width_px)
    with output_file(cfg.out_png):
        write_png(fig, cfg.out_png)
    write_config(config_path, cfg)
    return size


# -------------------------------------------------------------------------------------- convert
@dataclass
class ConvertReplicaOccConfig:
    """Options of ``panovocc convert replicaocc``.

    pkl : ``global_occ_package/<scene>.pkl`` (dense or flat form); out_npz : output grid
    class_names : names of the ids (a file, ``replica`` or a comma list); None: the file's
        ``class_names`` key, else FreeOcc's Replica list
    voxel_size : metres (None: the file's ``voxel_size`` key, else 0.08)
    tol_m : metres a centre may be off the lattice (None: a quarter voxel)
    allow_shift : translate an off-lattice grid onto the lattice
    """

    pkl: Path = option(argument=True, metavar="PKL",
                       help="ReplicaOcc/FreeOcc global_occ_package/<scene>.pkl (dense or flat form).")
    out_npz: Path = option(argument=True, metavar="OUT_NPZ", help="Output grid .npz.")
    class_names: str | None = option(
        None, help="Names of the label ids: a text file (one a line), 'replica' or a comma list; ids 1.. unless the "
                   "first name is empty/free/unlabeled (then ids 0..). Default: the file's class_names key, else "
                   "FreeOcc's replica_name.txt (101).")
    voxel_size: float | None = option(
        None, min=0, min_open=True, max=MAX_VOXEL_SIZE,
        help=f"Voxel edge, metres (default: the file's voxel_size key, else {DEFAULT_VOXEL_SIZE}).")
    tol_m: float | None = option(None, min=0, help="Metres a centre may be off the lattice (default: a quarter voxel).")
    allow_shift: bool = option(False, help="Translate an off-lattice grid onto the lattice.")
    overwrite: bool = option(False, help="Replace an existing OUT_NPZ (never an input).")


def run_convert_replicaocc(cfg: ConvertReplicaOccConfig):
    """ReplicaOcc ``.pkl`` -> grid ``.npz``.

    Returns
    -------
    grid : Grid; shift : (3,) metres the grid was moved by; names_from : ``given``, ``file`` or
    ``replica`` (FreeOcc's Replica list)
    """
    from ..io.replicaocc import class_names_source, load_pickle, parse_class_names, replicaocc_to_grid

    cfg = validate_config(cfg)
    names_file = Path(cfg.class_names) if cfg.class_names and "," not in cfg.class_names else None
    check_output(cfg.out_npz, "grid", cfg.overwrite, inputs=(cfg.pkl, names_file), folder=False)
    names = parse_class_names(cfg.class_names) if cfg.class_names is not None else None
    data = load_pickle(cfg.pkl)
    grid, shift = replicaocc_to_grid(data, names, cfg.voxel_size, cfg.tol_m, cfg.allow_shift, cfg.pkl)
    with output_file(cfg.out_npz):
        write_grid(cfg.out_npz, grid)
    return grid, shift, class_names_source(data, names)


@dataclass
class ConvertToReplicaOccConfig:
    """Options of ``panovocc convert to-replicaocc``.

    grid : grid ``.npz``; out_pkl : output ``.pkl`` (dense form, FreeOcc's loader reads it)
    ids : ``replica`` (FreeOcc's ids, 1 + line of replica_name.txt) or ``own`` (the grid's ids)
    prediction : the grid is a prediction: unknown (255) is written as 0 (FreeOcc counts > 0 as occupied)
    like : a grid ``.npz`` (the ground truth) whose voxels the output covers, so FreeOcc's
        index-by-index comparison lines up; None: the grid's own extent
    """

    grid: Path = option(argument=True, metavar="GRID", help="Grid .npz (ground truth or prediction).")
    out_pkl: Path = option(argument=True, metavar="OUT_PKL",
                           help="Output .pkl in FreeOcc's dense global_occ_package form.")
    ids: str = option("replica", choices=("replica", "own"),
                      help="Label ids to write: replica (FreeOcc's, 1 + line of replica_name.txt, matched by name) | "
                           "own (the grid's).")
    prediction: bool = option(False, help="The grid is a prediction: write unknown (255) as 0, since FreeOcc's "
                                          "scripts count every label > 0 as occupied.")
    like: Path | None = option(None, help="Ground-truth grid .npz whose voxels to write (FreeOcc compares arrays "
                                          "index by index).")

    overwrite: bool = option(False, help="Replace an existing OUT_PKL (never an input).")

def run_convert_to_replicaocc(cfg: ConvertToReplicaOccConfig):
    """Grid ``.npz`` -> dense ReplicaOcc ``.pkl``.

    Returns
    -------
    grid : the Grid written (on ``like``'s voxels when given); unmatched : class names written as 254
    """
    from ..grid import Grid
    from ..io.replicaocc import write_replicaocc
    from .align import resample_onto

    cfg = validate_config(cfg)
    check_output(cfg.out_pkl, "pickle", cfg.overwrite, inputs=(cfg.grid, cfg.like), folder=False)
    grid = read_grid(cfg.grid)
    if cfg.like is not None:
        ref = read_grid(cfg.like)
        try:
            labels = resample_onto(grid, ref)
        except PanovoccError as e:
            raise PanovoccError(f"{cfg.grid} vs {cfg.like}: {e}") from None
        grid = Grid(labels, ref.origin, ref.voxel_size, grid.class_names)
    with output_file(cfg.out_pkl):
        unmatched = write_replicaocc(cfg.out_pkl, grid, cfg.ids, cfg.prediction)
    return grid, unmatched


@dataclass
class SegevalConfig:
    """``panovocc segeval``: the segmenter's own per-frame 2D mIoU on a labelled sequence."""

    seq: str = option(cli_type=Path, parse=str, argument=True, metavar="SEQ",
                      help="Sequence folder with ground-truth labels (semantic/).")
    segmenter: str = option("simulated", help="Segmenter to score: simulated | precomputed:DIR.")
    vocab: object = option(None, cli_type=str, help="Vocabulary (as for map); default eval8,open4.")
    noise: float = option(1.0, min=0, help="Simulated segmenter noise level (dimensionless; 0 = exact).")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Seed of the simulated segmenter's noise.")
    classes: str = option("eval8", help="Scored class set: eval8 | open4 | eval12 | comma list (a,b,c).")
    every: int = option(1, min=1, help="Score every K-th frame (frames 0, K, 2K, ...).")


def run_segeval(cfg: SegevalConfig, progress: bool = True):
    """Pooled 2D mIoU of the segmenter over frames ``0, every, 2 every, ...`` of ``cfg.seq``.

    Returns
    -------
    (Miou2D, frames) : the pooled result (.miou, .iou, .accuracy) and the scored frame indices

    Raises
    ------
    PanovoccError
        Bad ``every``, no labels, a bad vocabulary or class list, or a class list none of whose classes
        occur in the sequence's class names (a mean over no class).
    """
    from ..classes import canonical_name, parse_class_set, parse_vocab
    from ..io.sequence import Sequence
    from ..semantics.metrics2d import empty_scores, frame_scores
    from ..semantics.registry import SEGMENTER_AUTO, SIMULATED, build_segmenter
    from ..semantics.simulated import sequence_label_source

    cfg = validate_config(cfg)  # noise, seed, every: the ranges declared on SegevalConfig
    seq = Sequence(cfg.seq)
    if not seq.has_labels:
        raise PanovoccError("segeval needs ground-truth labels (semantic/)", seq.root)
    names = list(seq.meta.class_names)
    vocab = parse_vocab(cfg.vocab, names, what="vocabulary (--vocab)")
    classes = parse_class_set(cfg.classes, names)
    known = {canonical_name(n) for n in names[1:]}
    if not any(c in known for c in classes):
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the sequence's labels "
                            f"(its classes: {', '.join(sorted(known))})", seq.root / "meta.json")
    spec = cfg.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        spec = SIMULATED
    seg = build_segmenter(spec, seed=int(cfg.seed), noise=float(cfg.noise), label_source=sequence_label_source(seq))
    frames = list(range(0, len(seq), cfg.every))
    total = empty_scores(classes)
    it = frames
    if progress:
        from tqdm import tqdm

        it = tqdm(frames, desc="2D mIoU", unit="frame")
    for i in it:
        logits = seg.logits(seq.rgb(i), vocab, frame_id=i)
        total.add(frame_scores(np.argmax(logits, axis=-1), vocab, seq.labels(i), names, classes))
    if not total.present.any():
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the labels of the scored frames",
                            seq.root)
    return total, frames
