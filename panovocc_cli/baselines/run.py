"""``panovocc baselines run NAME SEQ OUT``: a baseline on a panoramic sequence, scored like the mapper.

The baselines get exactly what ``panovocc map`` gets: the sequence's frames, the same poses (SEQ/poses.txt or
``--poses``), the same segmenter built the same way (:func:`panovocc_cli.mapping.pipeline.sequence_frames`:
the same spec, vocabulary, noise and seed give the same per-pixel output), the same voxel size and range.
Output folder (docs/baselines.md)::

    OUT/prediction.npz      the baseline's grid (CONVENTIONS.md), scored by ``panovocc eval``
    OUT/baseline.json       what ran and its counts (the folder's marker)
    OUT/config.json         the resolved options (io/runconfig.py)
    OUT/streams/NAME.npz    persp-tsdf: each view stream's own grid (merged into prediction.npz)
    OUT/frames/NNNNNN.npz   single-pano: each frame's local grid
    OUT/per_frame.csv       single-pano with --gt: each frame scored in its own volume
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import DEFAULT_SEED, DEFAULT_VOXEL_SIZE, MAX_SEED, MAX_STRIDE, MAX_VOXEL_SIZE, option, validate_config
from ..errors import PanovoccError
from ..evaluation.trajectory import PLACEMENTS
from ..geometry.cameras import TWELVE_PITCH_DEG
from .single_pano import EMBODIEDOCC_BOX_M, VERTICAL

BASELINES = ("persp-tsdf", "single-pano", "forward-only")
#: Marker file of a baselines output folder (``io.atomic.OUTPUT_MARKERS["baseline"]``).
BASELINE_JSON = "baseline.json"


def parse_box(text) -> tuple[float, float, float]:
    """``"4.8,4.8,2.88"`` -> (4.8, 4.8, 2.88) metres; three positive numbers."""
    if isinstance(text, (tuple, list)):
        parts = list(text)
    else:
        parts = [p for p in str(text).replace("x", ",").split(",") if p.strip()]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise PanovoccError(f"--box must be three positive sizes in metres, x,y,z (e.g. 4.8,4.8,2.88), got {text!r}")
    return vals


@dataclass
class BaselineConfig:
    """Options of ``panovocc baselines run`` (each field's help is its ``--help`` text; docs/baselines.md)."""

    name: str = option(argument=True, metavar="NAME", choices=BASELINES,
                       help="Baseline: persp-tsdf (twelve view streams, Open3D TSDF, merged) | single-pano (each "
                            "panorama alone in a local box) | forward-only (the forward middle view, one stream).")
    seq: Path = option(argument=True, metavar="SEQ", help="Panoramic (ERP) sequence folder (as for map).")
    out: Path = option(argument=True, metavar="OUT", help="Output folder: prediction.npz, baseline.json, "
                                                           "config.json (and streams/ or frames/).")
    poses: Path | None = option(None, help="Pose file (NICE-SLAM or TUM); default SEQ/poses.txt.")
    poses_align: str = option("none", choices=PLACEMENTS,
                              help="Align the --poses trajectory to SEQ/poses.txt first, as for map (se3: Umeyama, "
                                   "what the benchmark does with the SLAM front end's poses; se3-pose: whole poses).")
    voxel_size: float = option(DEFAULT_VOXEL_SIZE, min=0, min_open=True, max=MAX_VOXEL_SIZE,
                               help="Voxel edge length h, metres.")
    max_range: float = option(12.0, min=0, min_open=True, help="Depths farther than this are ignored, metres.")
    segmenter: str = option("auto", show_default=False,
                            help="Semantic segmenter, as for map: simulated | precomputed:DIR | none. Default: "
                                 "simulated when SEQ has labels, else none.")
    vocab: str | None = option(None, help="Vocabulary, as for map (e.g. eval8,open4); default eval8,open4.")
    noise: float = option(1.0, min=0, help="Simulated segmenter noise level (dimensionless; 0 = exact).")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Seed of the simulated segmenter's noise.")
    semantic_stride: int = option(0, min=0, max=MAX_STRIDE, help="The segmenter sees every s-th pixel, as for map; "
                                                                 "0 = auto, max(1, W // 512) (map's default).")
    fov_deg: float = option(90.0, min=10.0, max=170.0, help="persp-tsdf, forward-only: field of view of each "
                                                              "view, degrees.")
    size: int | None = option(None, min=8, max=4096, show_default="ERP width / 4",
                              help="persp-tsdf, forward-only: view width = height, pixels.")
    pitch_deg: float = option(TWELVE_PITCH_DEG, min=0.0, max=90.0,
                              help="persp-tsdf: pitch of the upper (+) and lower (-) view rows, degrees.")
    weight_threshold: float = option(1.0, min=0, help="persp-tsdf, forward-only: least TSDF weight (frames) of "
                                                      "an occupied or free voxel.")
    box: str = option(",".join(f"{v:g}" for v in EMBODIEDOCC_BOX_M),
                      help="single-pano: local box x,y,z in metres (EmbodiedOcc's by default).")
    vertical: str = option("floor", choices=VERTICAL, help="single-pano: box placement in height: floor (stands "
                                                           "on the floor seen in the frame) | camera (centred).")
    use_gsc: bool = option(True, flag="--no-gsc", negate=True, help="single-pano: raw argmax, no GSC (as map).")
    gt: Path | None = option(None, help="single-pano: ground-truth grid; score each frame in its own box "
                                        "(OUT/per_frame.csv).")
    classes: str = option("eval8", help="single-pano --gt: class set of the per-frame mIoU (as for eval).")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous baselines output in OUT (never any other folder).")


def _map_config(cfg: BaselineConfig, seq):
    """The MapConfig ``panovocc map`` would resolve for the same options (stride, vocabulary, segmenter)."""
    from ..mapping.config import MapConfig, SemanticParams
    from ..mapping.params import GeometryParams
    from ..mapping.pipeline import resolve, resolve_semantic

    mc = MapConfig(seq=str(cfg.seq), out=str(cfg.out), poses=None if cfg.poses is None else str(cfg.poses),
                   poses_align=cfg.poses_align,
                   geometry=GeometryParams(voxel_size=cfg.voxel_size, max_range=cfg.max_range),
                   semantic_stride=cfg.semantic_stride,
                   semantic=SemanticParams(segmenter=cfg.segmenter, vocab=cfg.vocab, noise=cfg.noise, seed=cfg.seed,
                                           use_gsc=cfg.use_gsc))
    mc = resolve(mc, seq.meta.width)
    return dataclasses.replace(mc, semantic=resolve_semantic(mc.semantic, seq))


def run_baseline(cfg: BaselineConfig) -> dict:
    """Run baseline ``cfg.name`` on ``cfg.seq`` and write ``cfg.out`` (module docstring); returns the summary
    written to ``OUT/baseline.json``."""
    from tqdm import tqdm

    from ..geometry.cameras import ViewRig
    from ..io.atomic import atomic_dir, check_output, write_text
    from ..io.grid import read_grid, write_grid
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from ..io.sequence import Sequence, frame_stem
    from ..mapping.pipeline import map_inputs, sequence_frames
    from .merge import merge_dense

    cfg = validate_config(cfg)
    box = parse_box(cfg.box)
    if cfg.gt is not None and cfg.name != "single-pano":
        raise PanovoccError(f"--gt scores single-pano's frames in their own boxes; score {cfg.name} with "
                            f"panovocc eval {cfg.out}/prediction.npz GT.npz")
    aligned = None
    if cfg.poses_align != "none":  # the map's reading of --poses with --poses-align (Umeyama to SEQ/poses.txt)
        from ..mapping.config import MapConfig
        from ..mapping.pipeline import run_poses

        aligned = run_poses(MapConfig(seq=str(cfg.seq), out=str(cfg.out), poses=(
            None if cfg.poses is None else str(cfg.poses)), poses_align=cfg.poses_align))
    seq = Sequence(cfg.seq, cfg.poses, aligned)
    if seq.meta.camera != "erp":
        raise PanovoccError(f"camera is {seq.meta.camera!r}; the baselines read panoramic (erp) sequences",
                            Path(cfg.seq) / "meta.json")
    if len(seq) == 0:
        raise PanovoccError("sequence has no frames", Path(cfg.seq) / "meta.json")
    if cfg.name == "single-pano":
        from ..runtime import check_memory
        from .single_pano import single_pano_memory

        n, need = single_pano_memory(box, cfg.voxel_size, seq.poses)
        check_memory(need, f"--box {cfg.box} at {cfg.voxel_size:g} m ({n[0]}x{n[1]}x{n[2]} voxels a frame, {len(seq)} "
                           "frames)", "choose a smaller --box or a larger --voxel-size")
    mc = _map_config(cfg, seq)
    check_output(cfg.out, "baseline", cfg.overwrite, inputs=(*map_inputs(mc), cfg.gt))
    gt = read_grid(cfg.gt) if cfg.gt is not None else None
    if gt is not None:  # the per-frame scores' class set, checked before the first frame is mapped
        from ..classes import parse_class_set

        parse_class_set(cfg.classes, gt.class_names)
    frames = sequence_frames(mc, seq)  # the map's segmenter, built the map's way
    vocab = list(mc.semantic.vocab) if mc.semantic.enabled else []
    seq.check_files(("depth", "rgb") + (("semantic",) if mc.semantic.segmenter == "simulated" else ()))
    n = len(seq)
    t0 = time.perf_counter()
    stream = (frames(i) for i in tqdm(range(n), desc=cfg.name, unit="frame", file=sys.stderr,
                                      disable=not cfg.progress))
    extra: dict[str, object] = {}
    files: dict[str, object] = {}
    rows = []
    g = mc.geometry
    if cfg.name in ("persp-tsdf", "forward-only"):
        from .forward_only import forward_only, forward_view
        from .persp_tsdf import persp_tsdf

        size = cfg.size if cfg.size is not None else max(8, seq.meta.width // 4)
        rig = ViewRig.twelve(size, math.radians(cfg.fov_deg), math.radians(cfg.pitch_deg))
        kw = dict(min_range=g.min_range, max_range=g.max_range, weight_threshold=cfg.weight_threshold)
        if cfg.name == "persp-tsdf":
            pred, grids = persp_tsdf(stream, rig, vocab, g.voxel_size, **kw)
            files = {f"streams/{v.name}.npz": gr for v, gr in zip(rig, grids)}
            extra["views"] = rig.names
        else:
            pred = forward_only(stream, rig, vocab, g.voxel_size, **kw)
            extra["views"] = [rig[forward_view(rig)].name]
        extra.update(view_size=size, fov_deg=cfg.fov_deg)
    else:
        from ..evaluation.metrics import evaluate
        from .single_pano import single_pano

        locals_, pairs, scores = [], [], []
        for i, lbox, grid in single_pano(stream, mc.mapper_config(), box, cfg.vertical):
            locals_.append(grid)
            files[f"frames/{frame_stem(i)}.npz"] = grid
            if gt is not None:
                pair = (grid, lbox.crop(gt))  # the ground truth cut to the frame's box
                pairs.append(pair)
                r = evaluate([pair], cfg.classes)["freeocc"]
                scores.append((r.iou, r.miou))
                rows.append([i, *(_pct(x) for x in (r.iou, r.miou, r.miou_present))])
        pred = merge_dense(locals_)
        extra.update(box_m=list(box), box_voxels=list(locals_[0].labels.shape), vertical=cfg.vertical)
        if gt is not None:
            r = evaluate(pairs, cfg.classes)["freeocc"]
            extra["per_frame"] = {"classes": cfg.classes, "pooled_iou": _pct(r.iou), "pooled_miou": _pct(r.miou),
                                  "mean_iou": _pct(_nanmean([s[0] for s in scores])),
                                  "mean_miou": _pct(_nanmean([s[1] for s in scores]))}
    seconds = time.perf_counter() - t0
    occ = (pred.labels != 0) & (pred.labels != 255)
    summary = {"baseline": cfg.name, "seq": str(cfg.seq), "frames": n, "vocab": vocab,
               "segmenter": mc.semantic.segmenter if mc.semantic.enabled else "none",
               "voxel_size": g.voxel_size, "occupied": int(occ.sum()),
               "classed": int((occ & (pred.labels < 254)).sum()), **extra}
    with atomic_dir(cfg.out) as tmp:
        write_grid(tmp / "prediction.npz", pred)
        for rel, grid in files.items():
            (tmp / rel).parent.mkdir(exist_ok=True)
            write_grid(tmp / rel, grid)
        if rows:
            from ..io.tables import write_csv

            write_csv(tmp / "per_frame.csv", ["frame", "iou", "miou", "miou_present"], rows)
        write_text(tmp / BASELINE_JSON, json.dumps(summary, indent=2) + "\n")
        write_run_config(tmp / CONFIG_NAME, cfg)
    return {**summary, "seconds": seconds, "out": str(cfg.out)}


def _nanmean(values) -> float:
    """Mean of the finite values (NaN when there is none: every frame's score undefined)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else math.nan


def _pct(x: float) -> float | None:
    """A percentage rounded to 1e-4 for the JSON/CSV outputs (NaN: None)."""
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


# ---------------------------------------------------------------------------------------------- merge
MERGE_KINDS = ("auto", "dense", "sparse")


@dataclass
class MergeConfig:
    """Options of ``panovocc baselines merge`` (docs/baselines.md, "Imported baselines").

    out : the merged grid .npz (``OUT.config.json`` beside it); inputs : one prediction per view sequence:
    grid .npz (dense), ReplicaOcc/FreeOcc .pkl (dense) or sparse voxels .npz (io/sparse_voxels.py)
    """

    out: Path = option(argument=True, metavar="OUT", help="Merged grid .npz to write (OUT.config.json beside it).")
    inputs: list = dataclasses.field(default_factory=list)
    kind: str = option("auto", choices=MERGE_KINDS, help="Input kind: dense (label grids: class voting) | sparse "
                                                         "(scored voxels: maximum confidence) | auto (from the files).")
    class_names: str | None = option(None, help="ReplicaOcc .pkl inputs: names of the label ids (a file, 'replica' "
                                                "or a comma list; as for convert replicaocc).")
    voxel_size: float | None = option(None, min=0, min_open=True, max=MAX_VOXEL_SIZE,
                                      help=f"ReplicaOcc .pkl inputs: voxel edge, metres (default: the file's, else "
                                           f"{DEFAULT_VOXEL_SIZE}).")
    overwrite: bool = option(False, help="Replace an existing OUT (never an input).")


def read_prediction(path: Path, class_names=None, voxel_size=None):
    """One input of a merge: ``("dense", Grid)`` or ``("sparse", SparseVoxels)`` by its content."""
    from ..io.grid import read_grid
    from ..io.sparse_voxels import is_sparse_npz, read_sparse_voxels
    from .merge import SparseVoxels

    path = Path(path)
    if not path.is_file():
        raise PanovoccError("prediction file not found", path)
    if path.suffix.lower() in (".pkl", ".pickle"):
        from ..io.replicaocc import read_replicaocc

        return "dense", read_replicaocc(path, class_names, voxel_size)[0]
    if path.suffix.lower() != ".npz":
        raise PanovoccError("expected a grid .npz, a sparse voxels .npz or a ReplicaOcc .pkl", path)
    if is_sparse_npz(path):
        return "sparse", SparseVoxels(*read_sparse_voxels(path))
    return "dense", read_grid(path)


def run_merge(cfg: MergeConfig) -> dict:
    """Merge ``cfg.inputs`` by the paper's rule into ``cfg.out``; returns counts."""
    from ..io.atomic import output_file
    from ..io.grid import write_grid
    from ..io.replicaocc import parse_class_names
    from ..io.runconfig import check_file_output, write_run_config
    from .merge import merge_dense, merge_sparse

    cfg = validate_config(cfg)
    if not cfg.inputs:
        raise PanovoccError("nothing to merge: give one prediction file per view sequence")
    config_path = check_file_output(cfg.out, "grid", cfg.overwrite, inputs=cfg.inputs)
    names = parse_class_names(cfg.class_names) if cfg.class_names is not None else None
    read = [(Path(p), *read_prediction(Path(p), names, cfg.voxel_size)) for p in cfg.inputs]
    kinds = {k for _, k, _ in read}
    kind = cfg.kind
    if kind == "auto":
        if len(kinds) > 1:
            first_sparse = next(p for p, k, _ in read if k == "sparse")
            raise PanovoccError("mixes sparse voxels with dense grids; merge one kind at a time (the rules differ)",
                                first_sparse)
        kind = kinds.pop()
    for p, k, _ in read:
        if k != kind:
            raise PanovoccError(f"is a {k} prediction; --kind {kind} expects {kind} inputs", p)
    items = [x for _, _, x in read]
    from ..runtime import check_memory
    from .merge import merge_memory

    shape, need = merge_memory(items, kind)
    check_memory(need, f"the inputs span a {shape[0]}x{shape[1]}x{shape[2]} grid, which",
                 "check the inputs' voxel coordinates (a voxel far from the others)")
    grid = merge_dense(items) if kind == "dense" else merge_sparse(items)
    with output_file(cfg.out):
        write_grid(cfg.out, grid)
        write_run_config(config_path, cfg)
    occ = (grid.labels != 0) & (grid.labels != 255)
    return {"inputs": len(items), "kind": kind, "occupied": int(occ.sum()),
            "classed": int((occ & (grid.labels < 254)).sum()), "shape": list(grid.labels.shape), "out": str(cfg.out)}
