"""The semantic side of ``panovocc map``: a per-frame semantic contributor and the labelled export.

Per frame, the segmenter (``simulated`` or ``precomputed:DIR``) gives logits over the run's vocabulary;
:func:`semantics.evidence.frame_semantic_delta` turns them into sparse per-voxel sums, which are
quantised into memory channels and travel through the SAME delta mechanism as the geometry (delta
files, ``revise``, ``--resume``: the memory stays the exact integer sum of the retained deltas).

Channels (``C`` = vocabulary size):

==============  =====  ======  ============================================================
name            width  kind    content
==============  =====  ======  ============================================================
``E``           C      fixed   sum of eta * p (2^-16 resolution)
``S``           1      fixed   sum of eta
``rgb_sum``     3      int     plain sum of pixel colours (0..255 integers: exact as integers)
``normal_sum``  3      fixed   plain sum of unit normals
``count``       1      int     pixels (measurements)
==============  =====  ======  ============================================================

Overflow: eta <= 1 and |p|, |n| <= 1, so a frame adds at most (pixels in the voxel) * 2^16 to an E, S
or normal_sum entry. Even a whole 2048x1024 frame falling into one voxel adds 2^37; int64 holds 2^63,
i.e. 2^26 (67 million) such frames. Rounding error: at most 2^-17 per entry per frame (the per-frame
sum is rounded once), far below a single pixel's weight.

Export (:func:`label_occupied`): the occupied set comes from the geometry alone; over it,
``gsc.unaries`` (E/S, mean normal, mean colour), the mapper's signed score ``g`` and
``gsc.consolidate`` give a vocabulary index or -1 (grid label 254).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence as Seq

import numpy as np

from ..config import validate_config
from ..errors import PanovoccError
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from ..semantics.params import EvidenceWeights
from .config import (PLY_COLORS, SEGMENTER_AUTO, SEGMENTER_NONE, SegevalConfig,  # noqa: F401  (re-exports)
                     SemanticParams, mapper_gsc_params)
from .memory import ChannelSpec, Delta, quantize

UNCLASSED_COLOR = (160, 160, 160)  # map.ply colour of occupied voxels without a class


def resolve(p: SemanticParams, seq) -> SemanticParams:
    """Resolve ``auto``, the vocabulary and a precomputed folder; validate everything before any file is written.

    Parameters
    ----------
    p : SemanticParams as given by the user
    seq : io.sequence.Sequence, the sequence to be mapped

    Raises
    ------
    PanovoccError
        Empty/invalid vocabulary, unknown segmenter, negative noise, ``simulated`` (or ``auto``) on a
        sequence without ``semantic/`` labels, a precomputed folder that fails validation, bad ply_color.
    """
    from ..classes import parse_vocab
    from ..semantics.registry import build_segmenter, is_simulated

    if p.ply_color not in PLY_COLORS:
        raise PanovoccError(f"--ply-color must be one of {', '.join(PLY_COLORS)}, got {p.ply_color!r}")
    # an empty vocabulary is an error even for --segmenter none; 'all' = the sequence's classes
    vocab = parse_vocab(p.vocab, seq.meta.class_names if seq.has_labels else None, what="vocabulary (--vocab)")
    spec = p.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        if not seq.has_labels:
            raise PanovoccError("the sequence has no ground-truth labels (semantic/) for the default simulated "
                                "segmenter: pass --segmenter precomputed:DIR, or --segmenter none for geometry only",
                                seq.root)
        spec = "simulated"
    if spec == SEGMENTER_NONE:
        return dataclasses.replace(p, segmenter=SEGMENTER_NONE, vocab=[])
    if is_simulated(spec) and not seq.has_labels:
        raise PanovoccError("the simulated segmenter needs ground-truth labels (semantic/), which this sequence "
                            "lacks: pass --segmenter precomputed:DIR or --segmenter none", seq.root)
    if spec.startswith("precomputed:"):
        folder = spec[len("precomputed:"):]
        spec = "precomputed:" + (str(Path(folder).resolve()) if folder else "")
    seg = build_segmenter(spec, seed=int(p.seed), noise=float(p.noise))  # validates spec, noise, folder
    return dataclasses.replace(p, segmenter=seg.spec or spec, vocab=list(vocab))


def semantic_channels(n_classes: int) -> tuple[ChannelSpec, ...]:
    """Memory channels of the semantic contributor for a vocabulary of ``n_classes`` words."""
    return (ChannelSpec("E", n_classes, "fixed"), ChannelSpec("S", 1, "fixed"), ChannelSpec("rgb_sum", 3, "int"),
            ChannelSpec("normal_sum", 3, "fixed"), ChannelSpec("count", 1, "int"))


def quantize_semantic_delta(keys: np.ndarray, channels: dict) -> Delta:
    """Float sums of :func:`semantics.evidence.frame_semantic_delta` -> integer :class:`Delta`.

    keys : (n,) int64 sorted unique; channels : E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3)
    float64, count (n,) int64
    """
    return Delta(keys, {"E": quantize(channels["E"], "fixed"), "S": quantize(channels["S"], "fixed"),
                        "rgb_sum": quantize(channels["rgb_sum"], "int"),
                        "normal_sum": quantize(channels["normal_sum"], "fixed"),
                        "count": np.asarray(channels["count"], np.int64)})


def semantic_delta(depth: np.ndarray, rgb: np.ndarray, logits: np.ndarray, T_world_cam: np.ndarray,
                   voxel_size: float, weights: EvidenceWeights, min_range: float, max_range: float,
                   rays: np.ndarray | None = None) -> Delta:
    """One frame's quantised semantic delta from its depth, colours and segmenter logits (no I/O).

    Depths outside ``[min_range, max_range]`` (metres) are ignored, as in the geometry contributor.
    """
    from ..semantics.evidence import frame_semantic_delta

    depth = np.where((depth >= min_range) & (depth <= max_range), depth, 0.0).astype(np.float32)
    keys, ch = frame_semantic_delta(depth, rgb, logits, T_world_cam, voxel_size, weights, rays)
    return quantize_semantic_delta(keys, ch)


def label_occupied(occupied_keys: np.ndarray, channels: dict, g: np.ndarray, params: SemanticParams) -> np.ndarray:
    """Vocabulary index of each occupied voxel, or -1 (no class; exported as 254).

    Parameters
    ----------
    occupied_keys : (n,) int64 voxel keys (lattice.pack_keys)
    channels : dict of the occupied voxels' stored channels, rows aligned with ``occupied_keys``:
        E (n, C), S (n, 1), normal_sum (n, 3) fixed point; rgb_sum (n, 3), count (n, 1) int64
    g : (n,) float64, the mapper's signed score (per-frame support units, ~0..1 on surfaces)
    params : SemanticParams (use_gsc, gsc)

    Returns
    -------
    labels : (n,) int64 in -1..C-1
    """
    from ..geometry.lattice import unpack_keys
    from ..semantics.gsc import consolidate, unaries
    from .memory import FIXED_SCALE

    n = len(occupied_keys)
    if n == 0:
        return np.zeros(0, np.int64)
    E = channels["E"] / FIXED_SCALE
    S = channels["S"][:, 0] / FIXED_SCALE
    p, normals, colors = unaries(E, S, channels["normal_sum"] / FIXED_SCALE, channels["rgb_sum"], channels["count"][:, 0])
    return consolidate(unpack_keys(occupied_keys), p, S, np.asarray(g, np.float64), normals, colors,
                       use_gsc=params.use_gsc, params=params.gsc)


def apply_labels(grid: Grid, occupied_keys: np.ndarray, labels: np.ndarray, vocab: Seq[str]) -> Grid:
    """Write class labels into a three-state grid: occupied voxel -> 1 + label (254 where -1).

    The grid's class names become ``["empty"] + vocab``; free (0) and unobserved (255) voxels stay.
    """
    from ..geometry.lattice import unpack_keys

    out = grid.labels.copy()
    if len(occupied_keys):
        local = unpack_keys(occupied_keys) - grid.index0
        lab = np.asarray(labels, np.int64)
        out[tuple(local.T)] = np.where(lab >= 0, lab + 1, OCCUPIED_UNKNOWN_CLASS).astype(np.uint8)
    return Grid(out, grid.origin, grid.voxel_size, ["empty"] + list(vocab))


def class_colors(labels: np.ndarray, vocab: Seq[str]) -> np.ndarray:
    """(n, 3) uint8 colours: :func:`classes.class_color` of each label, grey for -1."""
    from ..classes import class_color

    table = np.array([class_color(c) for c in vocab] + [UNCLASSED_COLOR], np.uint8).reshape(-1, 3)
    lab = np.asarray(labels, np.int64)
    return table[np.where(lab >= 0, lab, len(vocab))]


# ---------------------------------------------------------------------------------------------
# Reference and diagnostics


def relabel_from_ground_truth(pred: Grid, gt: Grid, max_dist_vox: float = 0.0) -> Grid:
    """Reference "perfect labels" for a prediction's geometry: its occupied voxels labelled by the truth.

    Each occupied voxel of ``pred`` (label not 0/255) takes the ground-truth class at the same voxel when
    the truth has a class there (1..253). Elsewhere (the truth says empty, unknown or 254, or does not
    cover the voxel: a geometric false positive) it takes the class of the nearest ground-truth class
    voxel within ``max_dist_vox`` voxels (Euclidean), else 254.

    * ``max_dist_vox = 0``: the ceiling of any labelling of this occupied set under the FreeOcc protocol
      (a voxel the truth does not hold gets no class, so it adds no class false positive);
    * ``max_dist_vox = 2`` (the mapper's own transfer bound): what per-pixel ground-truth labels binned
      into the voxels give; a voxel of a thickened surface takes the class of the surface it belongs to,
      exactly as the mapper labels it from the pixels that fell into it.

    Free and unobserved voxels are unchanged.

    Parameters
    ----------
    pred, gt : Grid on the same lattice (same voxel size)
    max_dist_vox : float >= 0, voxels

    Returns
    -------
    Grid, ``pred``'s box, class names = ``gt.class_names``
    """
    from scipy.spatial import cKDTree

    from ..evaluation.align import check_same_voxel_size, resample_onto

    check_same_voxel_size(pred, gt, "prediction and ground truth")
    truth = resample_onto(gt, pred, fill=UNKNOWN)
    occ = (pred.labels != EMPTY) & (pred.labels != UNKNOWN)
    has_class = (truth != EMPTY) & (truth != UNKNOWN) & (truth != OCCUPIED_UNKNOWN_CLASS)
    out = pred.labels.copy()
    out[occ] = np.where(has_class[occ], truth[occ], OCCUPIED_UNKNOWN_CLASS)
    need = np.argwhere(occ & ~has_class)
    src = np.argwhere((gt.labels != EMPTY) & (gt.labels != UNKNOWN) & (gt.labels != OCCUPIED_UNKNOWN_CLASS))
    if max_dist_vox > 0 and len(need) and len(src):
        tree = cKDTree((src + gt.index0).astype(np.float64))
        dist, nn = tree.query((need + pred.index0).astype(np.float64), k=1,
                              distance_upper_bound=float(max_dist_vox) + 1e-9)
        ok = np.isfinite(dist)
        s_ijk = src[nn[ok]]
        out[tuple(need[ok].T)] = gt.labels[tuple(s_ijk.T)]
    return Grid(out, pred.origin, pred.voxel_size, list(gt.class_names))


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
    from ..semantics.registry import build_segmenter
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
        spec = "simulated"
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
