"""The pose-convention self-check of the dataset readers (``convert holo360d --check``, ``convert s2d3ds --check``).

A pose convention is right when it makes overlapping frames' depth agree. For pairs of frames, the depth
points of one frame are moved into the other's camera with the two poses and projected into its panorama;
a point *agrees* when its range is within ``max(CHECK_TOL_M, CHECK_TOL_REL * depth)`` of the depth measured
at one of the four pixel centres around its projection. The agreement (percent of points that land on valid
depth) is computed for every candidate convention; a wrong one moves the points to the wrong place and its
agreement drops. With frames that barely move every convention agrees; the report gives the pairs' median
baseline and rotation so that case is visible.
"""

from __future__ import annotations

import numpy as np

CHECK_TOL_M = 0.05
"""Metres: the smallest range difference at which two frames' depth disagree (the check)."""
CHECK_TOL_REL = 0.02
"""Fraction of the range added to the check's tolerance (depth error grows with range)."""
CHECK_PAIRS = 24
"""At most this many frame pairs are compared (evenly spread over the sequence)."""
CHECK_SAMPLES = 20000
"""Depth points drawn (a regular pixel grid) from each frame of a pair."""


def depth_agreement(depth_a: np.ndarray, T_a: np.ndarray, depth_b: np.ndarray, T_b: np.ndarray,
                    samples: int = CHECK_SAMPLES, tol_m: float = CHECK_TOL_M,
                    tol_rel: float = CHECK_TOL_REL) -> tuple[int, int]:
    """How many of frame b's depth points agree with frame a's depth.

    Parameters
    ----------
    depth_a, depth_b : (H, W) float, metres, radial, 0 = invalid (ERP, same size)
    T_a, T_b : (4, 4) float64 T_world_cam
    samples : about this many pixels of b are used (a regular grid)

    Returns
    -------
    agree : points of b whose range in a's camera is within ``max(tol_m, tol_rel * depth_a)`` of a's depth
    compared : points of b that land on a valid depth pixel of a
    """
    from ..geometry.erp import backproject, project, project_to_pixel, ray_directions

    H, W = depth_b.shape
    step = max(1, int(np.sqrt(H * W / max(1, samples))))
    rays = ray_directions(W, H)[::step, ::step]
    d = np.asarray(depth_b, dtype=np.float64)[::step, ::step]
    ok = d > 0
    p_b = backproject(d, rays)[ok]
    T = np.linalg.inv(T_a) @ T_b
    p_a = p_b @ T[:3, :3].T + T[:3, 3]
    u, v, r = project(p_a, W, H)
    row, col, _ = project_to_pixel(p_a, W, H)
    dA = np.asarray(depth_a, dtype=np.float64)
    valid = dA[row, col] > 0
    agree = np.zeros(len(r), bool)
    for dv in (0, 1):  # any of the four pixel centres around the projection (the panorama is sampled)
        for du in (0, 1):
            rr = np.clip(np.floor(v).astype(np.int64) + dv, 0, H - 1)
            cc = (np.floor(u).astype(np.int64) + du) % W
            d = dA[rr, cc]
            agree |= (d > 0) & (np.abs(r - d) <= np.maximum(tol_m, tol_rel * d))
    agree &= valid
    return int(agree.sum()), int(valid.sum())


def check_pairs(n: int, pairs: int = CHECK_PAIRS) -> list[tuple[int, int]]:
    """Frame pairs (i, i + 1) of an n-frame sequence, at most ``pairs`` of them, evenly spread."""
    if n < 2:
        return []
    first = np.unique(np.linspace(0, n - 2, min(pairs, n - 1)).round().astype(int))
    return [(int(i), int(i) + 1) for i in first]


def convention_report(depths: dict[int, np.ndarray], candidates: dict[str, dict[int, np.ndarray]],
                      pairs: list[tuple[int, int]], chosen: str) -> dict:
    """Agreement of the pairs' depth under each candidate convention.

    Parameters
    ----------
    depths : frame index -> (H, W) float32 metres, radial, for every frame of ``pairs``
    candidates : convention name -> {frame index -> (4, 4) float64 T_world_cam}
    pairs : (i, j) frame indices
    chosen : the name of the convention in use

    Returns
    -------
    dict: ``chosen``, ``agreement`` percent for it, ``all`` {name: percent}, ``best``, ``median_baseline_m``,
    ``median_rotation_deg`` of the pairs (under the chosen convention), ``pairs``.
    """
    scores = {}
    for name, T in candidates.items():
        agree = compared = 0
        for i, j in pairs:
            x, n = depth_agreement(depths[i], T[i], depths[j], T[j])
            y, m = depth_agreement(depths[j], T[j], depths[i], T[i])
            agree, compared = agree + x + y, compared + n + m
        scores[name] = 100.0 * agree / compared if compared else float("nan")
    T = candidates[chosen]
    base, rot = [], []
    for i, j in pairs:
        rel = np.linalg.inv(T[i]) @ T[j]
        base.append(float(np.linalg.norm(rel[:3, 3])))
        rot.append(float(np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1, 1)))))
    finite = {k: v for k, v in scores.items() if np.isfinite(v)}
    return {"chosen": chosen, "agreement": scores[chosen], "all": scores,
            "best": max(finite, key=finite.get) if finite else None,
            "median_baseline_m": float(np.median(base)) if base else float("nan"),
            "median_rotation_deg": float(np.median(rot)) if rot else float("nan"), "pairs": len(pairs)}
