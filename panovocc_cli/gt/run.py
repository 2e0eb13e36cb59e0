"""``run_gt``: the mesh ground truth of a scene, or (``--from-sequence``) the one lifted from a capture.

The reading and writing around :mod:`panovocc_cli.gt.mesh` and :mod:`panovocc_cli.gt.lifted`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import validate_config
from ..errors import PanovoccError
from ..gt_config import GtConfig
from .consensus import BYTES_PER_VOXEL, ConsensusLift
from .lifted import depth_bounds, parse_annotated


def run_gt(cfg: GtConfig) -> dict:
    """Build the ground truth ``cfg`` asks for and write the grid ``.npz`` (+ ``OUT.config.json``).

    Returns
    -------
    dict summary: shape, occupied, classes, voxel_size (and, lifted, the protocol's counts)
    """
    cfg = validate_config(cfg)  # voxel_size and the lifting knobs: the ranges declared on GtConfig
    if cfg.out is None:
        raise PanovoccError("gt needs OUT: panovocc gt SCENE OUT, or panovocc gt --from-sequence SEQ OUT")
    if cfg.from_sequence is not None:
        if cfg.scene is not None:
            raise PanovoccError("gt takes a SCENE or --from-sequence SEQ, not both")
        return run_lifted_gt(cfg)
    if cfg.scene is None:
        raise PanovoccError("gt needs SCENE and OUT (or --from-sequence SEQ OUT)")
    return run_mesh_gt(cfg)


def run_mesh_gt(cfg: GtConfig) -> dict:
    """Voxelise ``cfg.scene`` and write the grid ``.npz``; returns a summary dict."""
    from ..datasets.replica import read_replica_scene, scene_files
    from ..io.grid import write_grid
    from ..io.runconfig import check_file_output, write_run_config
    from .mesh import voxelize_scene

    config_path = check_file_output(cfg.out, "grid", cfg.overwrite, inputs=(cfg.scene, *scene_files(cfg.scene)))
    scene = read_replica_scene(cfg.scene)
    grid = voxelize_scene(scene, cfg.voxel_size)
    write_grid(cfg.out, grid)
    write_run_config(config_path, cfg)
    occ = (grid.labels > 0) & (grid.labels < 255)
    return {"shape": tuple(int(s) for s in grid.labels.shape), "occupied": int(occ.sum()),
            "classes": len(grid.class_names), "voxel_size": grid.voxel_size}


def accumulate_sequence(seq, voxel_size: float, lift, progress: bool = False) -> tuple[ConsensusLift, list[int]]:
    """Every frame of a :class:`~panovocc_cli.io.sequence.Sequence` given to a :class:`ConsensusLift` whose
    box holds all its depth: every frame's surface positions, the consensus, then every frame's rays
    (reads the depth files twice; checks them all first).

    Parameters
    ----------
    seq : Sequence (ERP), its poses T_world_cam
    voxel_size : h, metres
    lift : LiftParams (annotated, max_range and the consensus rules)

    Returns
    -------
    acc : ConsensusLift (settled, every frame's evidence in); annotated : the annotated frame numbers
    """
    from tqdm import tqdm

    from ..geometry.lattice import point_to_index
    from ..io.images import check_image_header
    from ..io.sequence import frame_stem
    from ..runtime import check_memory

    if seq.meta.camera != "erp":
        raise PanovoccError(f"camera {seq.meta.camera!r}: the lifted ground truth needs an ERP sequence",
                            seq.root / "meta.json")
    n = len(seq)
    if n == 0:
        raise PanovoccError("the sequence has no frames", seq.root / "meta.json")
    annotated = parse_annotated(lift.annotated, n)
    if annotated and not seq.has_labels:
        raise PanovoccError(f"--annotated {lift.annotated}: no semantic/ folder (the annotated frames' label PNGs)",
                            seq.root)
    seq.check_files(("depth",))
    for i in annotated:
        path = seq.root / "semantic" / f"{frame_stem(i)}.png"
        if not path.is_file():
            raise PanovoccError(f"label PNG of annotated frame {i} not found (--annotated {lift.annotated})", path)
        check_image_header(path, "labels", seq.meta.shape)
    h = float(voxel_size)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for i in tqdm(range(n), desc="gt bounds", unit="frame", disable=not progress):
        a, b = depth_bounds(seq.depth(i), seq.poses[i], lift.max_range)
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
    i0 = point_to_index(lo, h)
    shape = point_to_index(hi, h) - i0 + 1
    need = float(np.prod(shape.astype(np.float64))) * (BYTES_PER_VOXEL + 2)
    check_memory(need, f"the depth spans a {shape[0]}x{shape[1]}x{shape[2]} grid at {h:g} m, which",
                 "choose a larger --voxel-size or a --max-range", seq.root)
    acc = ConsensusLift(i0, shape, h, len(seq.meta.class_names), lift.max_range, min_points=lift.min_points,
                        min_frames=lift.min_frames, min_hit_ratio=lift.min_hit_ratio, surface_tol=lift.surface_tol,
                        surface_tol_r2=lift.surface_tol_r2)
    for i in tqdm(range(n), desc="gt surfaces", unit="frame", disable=not progress):
        acc.add_density(seq.depth(i), seq.poses[i])
    acc.settle()
    marked = set(annotated)
    for i in tqdm(range(n), desc="gt rays", unit="frame", disable=not progress):
        acc.add_evidence(seq.depth(i), seq.poses[i], seq.labels(i) if i in marked else None)
    return acc, annotated


def lift_sequence(seq, voxel_size: float, lift, progress: bool = False):
    """Lift a :class:`~panovocc_cli.io.sequence.Sequence` into a ground-truth grid (reads its files).

    Parameters
    ----------
    seq : Sequence (ERP), its poses T_world_cam
    voxel_size : h, metres
    lift : LiftParams

    Returns
    -------
    grid : Grid; stats : dict (frames, annotated, occupied, voted, transferred, no_class, free, unknown, modes)
    """
    acc, annotated = accumulate_sequence(seq, voxel_size, lift, progress)
    n = len(seq)
    grid = acc.grid(seq.meta.class_names, lift.label_radius)
    return grid, {"frames": n, "annotated": len(annotated), **acc.stats}


def run_lifted_gt(cfg: GtConfig) -> dict:
    """Lift ``cfg.from_sequence`` (docs/gt.md) and write the grid ``.npz`` + ``OUT.config.json``."""
    from ..io.grid import write_grid
    from ..io.runconfig import check_file_output, write_run_config
    from ..io.sequence import Sequence

    seq_root = Path(cfg.from_sequence)
    config_path = check_file_output(cfg.out, "grid", cfg.overwrite, inputs=(seq_root,))
    seq = Sequence(seq_root)
    grid, stats = lift_sequence(seq, cfg.voxel_size, cfg.lift, progress=cfg.progress)
    write_grid(cfg.out, grid)
    write_run_config(config_path, cfg)
    return {"shape": tuple(int(s) for s in grid.labels.shape), "classes": len(grid.class_names),
            "voxel_size": grid.voxel_size, **stats}
