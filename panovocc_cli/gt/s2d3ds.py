"""Ground truth of a Stanford 2D-3D-S area from its annotated point clouds (S3DIS ``Area_N/ROOM/Annotations``).

The rules are the mesh truth's (:mod:`.mesh`, ``panovocc gt``) with points in place of surface area, on the
same global lattice: a voxel is occupied when an annotated point falls in it (voxel n covers
[n h, (n+1) h); a point on a voxel face belongs to the voxel above it, the same ``GT_BOUNDARY_EPS`` as the
mesh truth); each occupied voxel takes the class with the most points in it (ties: the lower class id);
points of no class (id 0) count only where nothing else is (254). Every other voxel of the points' box is 0
(empty). The scanner's points are spread over the surfaces, so a point count stands for surface area.
Class names: the 13 of :data:`panovocc_cli.io.s2d3ds.S2D3DS_CLASSES` through ``CLASS_MAP``.

:func:`points_to_grid` is the maths; :func:`run_s2d3ds_gt` reads the files and writes ``GT.npz`` and
``GT.config.json``.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..config import GT_BOUNDARY_EPS, validate_config
from ..errors import PanovoccError
from ..geometry.lattice import index_to_center, pack_keys, unpack_keys
from ..grid import OCCUPIED_UNKNOWN_CLASS, Grid
from ..gt_config import S2d3dsGtConfig


def voxel_counts(points: np.ndarray, class_id: int, voxel_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keys (m,) int64 packed voxel indices, classes (m,) int64, counts (m,) int64): one class's points per voxel."""
    idx = np.floor(np.asarray(points, np.float64) / voxel_size + GT_BOUNDARY_EPS).astype(np.int64)
    k, c = np.unique(pack_keys(idx), return_counts=True)
    return k, np.full(len(k), int(class_id), np.int64), c.astype(np.int64)


def points_to_grid(counts: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], class_names, voxel_size: float) -> Grid:
    """The grid of accumulated :func:`voxel_counts`.

    Parameters
    ----------
    counts : (keys, classes, counts) of :func:`voxel_counts` (any order, any repeats: they are summed)
    class_names : list of str, ``class_names[0] == "empty"``; class ids index it (0 = no class)
    voxel_size : h, metres

    Returns
    -------
    Grid: 1..C the class with the most points (ties: the lower id), 254 points of no class only, 0 elsewhere
    in the points' box.
    """
    if len(class_names) > OCCUPIED_UNKNOWN_CLASS:
        raise PanovoccError(f"{len(class_names)} classes; a uint8 grid holds at most 253")
    parts = list(counts)
    if not parts or not sum(len(k) for k, _, _ in parts):
        raise PanovoccError("no annotated point to voxelise")
    pairs = np.stack([np.concatenate([k for k, _, _ in parts]), np.concatenate([c for _, c, _ in parts])], axis=1)
    uk, inv = np.unique(pairs, axis=0, return_inverse=True)
    tot = np.bincount(inv.reshape(-1), weights=np.concatenate([n for _, _, n in parts]).astype(np.float64))
    vox, cls = uk[:, 0], uk[:, 1]
    score = np.where(cls > 0, tot, -1.0)  # points of no class lose to any class
    order = np.lexsort((cls, -score, vox))  # per voxel: most points first, then the lower class id
    first = np.ones(len(order), bool)
    first[1:] = vox[order][1:] != vox[order][:-1]
    win = order[first]
    ijk = unpack_keys(vox[win])
    i0 = ijk.min(axis=0)
    shape = ijk.max(axis=0) - i0 + 1
    labels = np.zeros(tuple(int(s) for s in shape), np.uint8)
    labels[tuple((ijk - i0).T)] = np.where(cls[win] > 0, cls[win], OCCUPIED_UNKNOWN_CLASS).astype(np.uint8)
    return Grid(labels, index_to_center(i0, voxel_size), voxel_size, list(class_names)).validate()


def run_s2d3ds_gt(cfg: S2d3dsGtConfig) -> dict:
    """Voxelise the annotated points of ``cfg.annotations`` into ``cfg.out``; returns counts (``points``,
    ``skipped_lines``, ``rooms``, ``occupied``, ``classes`` {name: voxels}, ``unknown_classes``)."""
    from tqdm import tqdm

    from ..classes import canonical_name
    from ..io.grid import write_grid
    from ..io.runconfig import check_file_output, write_run_config
    from ..io.s2d3ds import CLASS_MAP, S2D3DS_CLASSES, annotation_class, list_annotations, read_annotation

    cfg = validate_config(cfg)
    config_path = check_file_output(cfg.out, "grid", cfg.overwrite, inputs=(cfg.annotations,))
    files = list_annotations(cfg.annotations)
    if cfg.rooms:
        want = {r.strip() for r in cfg.rooms.split(",") if r.strip()}
        have = {r for r, _ in files}
        if want - have:
            raise PanovoccError(f"--rooms: {', '.join(sorted(want - have))} not found (rooms: "
                                f"{', '.join(sorted(have))})", cfg.annotations)
        files = [(r, p) for r, p in files if r in want]
    names = ["empty"] + [CLASS_MAP[c] for c in S2D3DS_CLASSES]
    extra = sorted({canonical_name(annotation_class(p)) for _, p in files} - set(S2D3DS_CLASSES))
    names += [n for n in extra if n and n != "<unk>"]
    ids = {n: k for k, n in enumerate(names)}
    counts, points, skipped = [], 0, 0
    for room, path in tqdm(files, desc="gt", unit="file", disable=not cfg.progress):
        pts, bad = read_annotation(path)
        skipped += bad
        points += len(pts)
        if len(pts):
            cls = canonical_name(annotation_class(path))
            counts.append(voxel_counts(pts, ids.get(CLASS_MAP.get(cls, cls), 0), cfg.voxel_size))
    grid = points_to_grid(counts, names, cfg.voxel_size)
    write_grid(cfg.out, grid)
    write_run_config(config_path, cfg)
    hist = np.bincount(grid.labels.ravel(), minlength=256)
    return {"points": points, "skipped_lines": skipped, "rooms": len({r for r, _ in files}),
            "occupied": int(hist[1:255].sum()), "classes": {n: int(hist[k]) for k, n in enumerate(names) if k and hist[k]},
            "unknown_classes": extra, "path": str(cfg.out)}
