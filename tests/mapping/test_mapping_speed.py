"""The fast geometric update gives exactly the reference results; ``panovocc bench`` end to end."""


import numpy as np
import pytest
from box_room import HI, LO, box_depth, turned_pose

from panovocc_cli.errors import PanovoccError
from panovocc_cli.mapping.psvf.update import _delta_rows, _extract, frame_box
from panovocc_cli.mapping.freespace import carve

EPS_ABS, EPS_REL, STABLE_K, MIN_R, MAX_R = 0.07, 0.01, 2.0, 0.1, 12.0


def _atan2_poly(y, x):
    """The carve's polynomial atan2, transcribed in numpy (same operations in the same order)."""
    ax, ay = np.abs(x), np.abs(y)
    mx = np.maximum(ax, ay)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.minimum(ax, ay) / mx
    s = a * a
    r = ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a + 0.99997726 * a
    r = np.where(ay > ax, 0.5 * np.pi - r, r)
    r = np.where(x < 0.0, np.pi - r, r)
    r = np.where(y < 0.0, -r, r)
    return np.where(mx == 0.0, 0.0, r)


def _carve_reference(depth, T, h, lo, shape, extent):
    """The free-space test of freespace.py's docstring, written out voxel-parallel in numpy (float32
    where the numba code computes in float32)."""
    H, W = depth.shape
    Rt, t = T[:3, :3].T, T[:3, 3]
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, 3)
    c = (idx + lo + 0.5) * h - t
    p = [(Rt[a, 0] * c[:, 0] + Rt[a, 1] * c[:, 1]) + Rt[a, 2] * c[:, 2] for a in range(3)]
    r = np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    theta = _atan2_poly(p[0], p[2])
    phi = _atan2_poly(-p[1], np.sqrt(p[0] * p[0] + p[2] * p[2]))
    col = np.floor((theta + np.pi) * W / (2.0 * np.pi)).astype(np.int64) % W
    row = np.clip(np.floor((0.5 * np.pi - phi) * H / np.pi).astype(np.int64), 0, H - 1)
    ro32 = depth[row, col]
    ro = ro32.astype(np.float64)
    eps = EPS_ABS + EPS_REL * ro
    O = (r >= MIN_R) & (r <= MAX_R) & (ro > 0) & ~(r > ro + eps)
    q = [depth[row, (col - 1) % W], depth[row, (col + 1) % W], depth[np.maximum(row - 1, 0), col],
         depth[np.minimum(row + 1, H - 1), col]]
    tol = STABLE_K * eps
    stable = np.ones(len(r), bool)
    for qq in q:
        stable &= ~((qq <= 0) | (np.abs(qq - ro32) > tol))
    F = O & (r < ro - eps) & stable
    if extent:
        dth, dph = 2.0 * np.pi / W, np.pi / H
        phi_c = 0.5 * np.pi - (row + 0.5) * dph
        th_c = (col + 0.5) * dth - np.pi
        sp, cp, st, ct = np.sin(phi_c), np.cos(phi_c), np.sin(th_c), np.cos(th_c)
        with np.errstate(divide="ignore", invalid="ignore"):  # ro = 0 (dropouts): masked by O
            a = (q[1] - q[0]) / (2.0 * ro * dth * np.maximum(cp, 1e-3))
            b = (q[2] - q[3]) / (2.0 * ro * dph)
            n = [cp * st - a * ct + b * sp * st, -sp + b * cp, cp * ct + a * st + b * sp * ct]
            l1 = sum(np.abs(Rt[0, k] * n[0] + Rt[1, k] * n[1] + Rt[2, k] * n[2]) for k in range(3))
            F &= ~(r > ro - eps - 0.5 * h * l1)
    return F.reshape(tuple(shape)).astype(np.uint8), O.reshape(tuple(shape)).astype(np.uint8)


@pytest.mark.parametrize("extent", [True, False])
def test_carve_equals_numpy_reference_on_a_noisy_box_room(extent):
    """Same F and O bits as the reference on a box room (256 x 128) with depth noise and dropouts seen
    from a rotated, shifted camera; interior voxels far from the walls are carved, voxels outside are not."""
    W, h = 256, 0.08
    T = turned_pose()
    rng = np.random.default_rng(0)
    depth = (box_depth(W, T).astype(np.float64) + rng.normal(0, 0.01, (W // 2, W))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.01] = 0.0
    lo = np.floor(LO / h).astype(np.int64) - 5
    shape = np.floor(HI / h).astype(np.int64) + 5 - lo + 1
    F, O = carve(depth, T, h, lo, shape, EPS_ABS, EPS_REL, STABLE_K, MIN_R, MAX_R, extent)
    F_ref, O_ref = _carve_reference(depth, T, h, lo, shape, extent)
    np.testing.assert_array_equal(O, O_ref)
    np.testing.assert_array_equal(F, F_ref)
    centres = (np.argwhere(np.ones(tuple(shape), bool)) + lo + 0.5) * h
    inside = np.all((centres > LO + 0.4) & (centres < HI - 0.4), axis=1) & (
        np.linalg.norm(centres - T[:3, 3], axis=1) > 0.3)
    outside = np.any((centres < LO - 0.3) | (centres > HI + 0.3), axis=1)
    assert F.reshape(-1)[inside].mean() > 0.9  # 1% dropouts make ~5% of the pixels unstable
    assert O.reshape(-1)[outside].max() == 0


def test_extract_and_frame_box_match_numpy():
    rng = np.random.default_rng(1)
    shape = (13, 9, 7)
    A = np.where(rng.random(shape) < 0.3, rng.random(shape), 0.0)
    F = (rng.random(shape) < 0.4).astype(np.uint8)
    O = np.maximum(F, (rng.random(shape) < 0.2).astype(np.uint8))
    lo = np.array([-5, 3, -200], np.int64)
    hits = (rng.random(shape) < 0.1).astype(np.uint8)
    scale, n_fill = float(2 ** 16), np.int64(np.ceil(0.3 * 2 ** 16))
    a = np.rint(A * scale).astype(np.int64)
    n = ((hits != 0) | (a >= n_fill)).astype(np.int64)
    keep = (O != 0) | (a != 0) | (n != 0)
    ijk = np.argwhere(keep) + lo + (1 << 20)
    for observe_hits in (False, True):  # O counts a frame counted in N (True), or only comparisons (older maps)
        keys, rows = _delta_rows([_extract(A, hits, F, O, lo, scale, n_fill, observe_hits)])
        o = np.maximum(O, n) if observe_hits else O
        np.testing.assert_array_equal(keys, (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2])
        np.testing.assert_array_equal(rows, np.stack([a[keep], n[keep], F[keep], o[keep]], 1))
    assert (n > O).any()  # the case exists in this grid
    x = rng.normal(0, 2, (500, 3))
    half = rng.random((500, 3)) * 0.2
    cam = np.array([0.1, -0.3, 0.2])
    lo, shape = frame_box(x, half, 1.5, cam, 0.08, 3.0)
    pmin = np.maximum(np.minimum((x - 1.5 * half).min(0), cam), cam - 3.0)
    pmax = np.minimum(np.maximum((x + 1.5 * half).max(0), cam), cam + 3.0)
    np.testing.assert_array_equal(lo, np.floor(pmin / 0.08).astype(np.int64) - 1)
    np.testing.assert_array_equal(lo + shape - 1, np.floor(pmax / 0.08).astype(np.int64) + 1)


def test_radial_fit_selection_equals_a_sort():
    """The radial fit's selection equals a sort (process settings: tests/test_runtime.py)."""
    from panovocc_cli.mapping.psvf import noise_fit

    rng = np.random.default_rng(0)
    r = rng.uniform(0.2, 5.0, 4000)
    res2 = rng.exponential(1e-6, 4000)
    cinc = rng.uniform(0.3, 1.0, 4000)
    edges = np.arange(0.1, 12.5, 0.5)
    centres, qs, counts = noise_fit._binned_quantiles(r, res2, cinc, 0.3, edges, 0.25, 50)
    for c, q, n in zip(centres, qs, counts):
        sel = (r >= c - 0.25) & (r < c + 0.25)
        v = np.sort(res2[sel] / cinc[sel] ** 2)
        assert len(v) == n and q == v[int(0.25 * (n - 1))]
