"""PSVF kernel shape (equator vs pole) and free-space carving in a closed-form box room."""

import numpy as np
from box_room import HI, LO, box_depth
from psvf_reference import kernel_inverse_cov, kernel_params, measurement_weight

from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.geometry.lattice import index_to_center, unpack_keys
from panovocc_cli.mapping.contributors import geometry_delta
from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.freespace import carve
from panovocc_cli.mapping.memory import FIXED_SCALE
from panovocc_cli.mapping.psvf import lift_kernels, lift_surfels, splat, splat_axis


def test_fast_lift_matches_numpy_reference():
    W = 128
    depth = box_depth(W)
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]
    T[:3, 3] = [0.1, -0.2, 0.3]
    x, E, sigma, phi, r = kernel_params(depth, T, 2, 0.01, 0.02, 0.1, 12.0)
    P, half = kernel_inverse_cov(E, sigma)
    w = measurement_weight(phi, r, 0.5, 8.0)
    x2, P2, half2, w2 = lift_kernels(depth, T, 2, 0.01, 0.02, 0.1, 12.0, 0.5, 8.0, 1.0)
    np.testing.assert_allclose(x2, x, atol=1e-9)
    np.testing.assert_allclose(P2, P, rtol=1e-9)
    np.testing.assert_allclose(half2, half, rtol=1e-9)
    np.testing.assert_allclose(w2, w, rtol=1e-12)
    # E is orthonormal and its ray column points from the camera to the point
    np.testing.assert_allclose(np.einsum("nji,njk->nik", E, E), np.broadcast_to(np.eye(3), E.shape), atol=1e-12)
    np.testing.assert_allclose((x - T[:3, 3]) / r[:, None], E[:, :, 2], atol=1e-9)


def test_kernel_shape_equator_vs_pole():
    """At the equator the tangential scales are equal (r dtheta = r dphi); near a pole the longitude scale
    shrinks by |cos phi|, so the splat is elongated along the latitude direction only."""
    W, H, s = 256, 128, 4
    depth = np.zeros((H, W), np.float32)
    r = 3.0
    v_eq, v_pole = H // 2 + s // 2 - s, s // 2  # strided rows nearest the equator / the north pole
    u = W // 2 + s // 2
    depth[v_eq, u] = r
    depth[v_pole, u] = r
    x, E, sigma, phi, rr = kernel_params(depth, np.eye(4), s, 0.01, 0.02, 0.1, 12.0)
    eq, pole = np.argmin(np.abs(phi)), np.argmax(np.abs(phi))
    dth = 2 * np.pi * s / W
    np.testing.assert_allclose(sigma[eq], [r * np.cos(phi[eq]) * dth, r * np.pi * s / H, 0.01 * r + 0.02])
    np.testing.assert_allclose(sigma[eq, 0], sigma[eq, 1], rtol=1e-3)
    np.testing.assert_allclose(sigma[pole, 0] / sigma[pole, 1], np.cos(phi[pole]), rtol=1e-9)
    assert sigma[pole, 0] < 0.1 * sigma[pole, 1]
    # the splat: support along e_theta vs e_phi, measured on a fine lattice around each point
    h = 0.01
    P, half = kernel_inverse_cov(E, sigma)
    for n, elongated in ((eq, False), (pole, True)):
        lo = np.floor((x[n] - 2 * half[n]) / h).astype(np.int64) - 1
        shape = (np.ceil(4 * half[n] / h) + 3).astype(np.int64)
        A = splat(x[n:n + 1], P[n:n + 1], half[n:n + 1], np.ones(1), 2.0, h, lo, shape, "psvf")
        ijk = np.argwhere(A > 0)
        c = index_to_center(ijk + lo, h) - x[n]
        # every supported centre has the weight exp(-d^2/2) within d^2 <= kappa^2 (checked directly)
        d2 = np.einsum("ni,ij,nj->n", c, P[n], c)
        assert np.all(d2 <= 4.0 + 1e-9)
        np.testing.assert_allclose(A[tuple(ijk.T)], np.exp(-0.5 * d2), rtol=1e-12)
        ext_t = np.abs(c @ E[n][:, 0]).max()
        ext_p = np.abs(c @ E[n][:, 1]).max()
        if elongated:
            assert ext_p > 4 * ext_t
        else:
            assert 0.6 < ext_p / ext_t < 1.6


def test_free_space_carving_in_box_room():
    W, h = 256, 0.08
    depth = box_depth(W)
    lo = np.floor(LO / h).astype(np.int64) - 3
    shape = np.floor(HI / h).astype(np.int64) + 3 - lo + 1
    F, O = carve(depth, np.eye(4), h, lo, shape, 0.07, 0.01, 2.0, 0.1, 12.0)
    c = index_to_center(np.argwhere(np.ones(tuple(shape), bool)) + lo, h).reshape(tuple(shape) + (3,))
    inside_margin = np.minimum(c - LO, HI - c).min(axis=-1)  # distance to the nearest wall, <0 outside
    r = np.linalg.norm(c, axis=-1)
    deep = (inside_margin > 0.07 + 0.01 * 3.0 + 0.08) & (r > 0.1)
    assert F[deep].all() and O[deep].all()  # every voxel well inside the room is carved
    assert not F[inside_margin <= 0.0].any()  # no centre on or behind a wall is free
    # seen head-on (the ray meets the wall at a right angle) a centre within eps of the wall is not carved
    head_on = (np.abs(c[..., 0]) < 0.3) & (np.abs(c[..., 2]) < 0.3) & (HI[1] - c[..., 1] < 0.07)
    assert head_on.any() and not F[head_on].any()
    outside = inside_margin < -(0.07 + 0.01 * 3.5)
    # occluded voxels behind the walls: no comparison, except where a pixel straddles a room edge
    # (its centre ray sees the farther wall): a thin fringe along the 12 edges
    assert O[outside].mean() < 0.01 and not F[outside].any()


def test_geometry_delta_supports_walls_and_carves_interior():
    W, h = 256, 0.08
    T = np.eye(4)
    depth = box_depth(W, T)
    for kernel in ("psvf", "point"):
        d = geometry_delta(depth, T, GeometryParams(voxel_size=h, stride=1, kernel=kernel))
        assert np.all(np.diff(d.keys) > 0)
        c = index_to_center(unpack_keys(d.keys), h)
        margin = np.minimum(c - LO, HI - c).min(axis=-1)
        A = d.channels["A"][:, 0]
        # a frame counts in N where one of its measurements lies in the voxel (on a wall here) or, for
        # psvf, where its support reaches n_fill
        N = d.channels["N"][:, 0] > 0
        if kernel == "psvf":
            assert np.all(N[A >= np.ceil(GeometryParams().n_fill * FIXED_SCALE)])
        else:
            assert np.array_equal(N, A > 0)
        assert np.all(np.abs(margin[N]) < h / 2 + 1e-9)  # only voxels that a wall passes through
        assert N[np.abs(margin) < h / 2 - 1e-3].mean() > 0.95
        assert np.all(np.abs(margin[A > 0]) < 0.16)  # support only near the walls
        on_wall = np.abs(margin) < h / 2
        assert (A[on_wall] > 0).mean() > 0.95  # and the walls are supported
        assert not np.any((d.channels["F"][:, 0] > 0) & (A > 0) & (np.abs(margin) < h / 2))


def test_box_extent_kernel_closed_form():
    """extent=box: tangential Gaussian times P(ray coordinate inside the voxel's chord through its centre)."""
    from math import erf

    h, kappa, s_r = 0.08, 2.0, 0.02
    W = 256
    depth = np.zeros((W // 2, W), np.float32)
    depth[W // 4 + 2, W // 2 + 2] = 2.0
    x, P, half, w = lift_kernels(depth, np.eye(4), 1, 0.0, s_r, 0.1, 12.0, 1.0, 1e9, 1.0)
    assert np.all(kappa * half[0] + h < 4 * h)  # the 9^3 grid holds the whole kernel
    er = x / np.linalg.norm(x, axis=1, keepdims=True)
    sr = np.full(1, s_r)
    lo = np.floor(x[0] / h).astype(np.int64) - 4
    A = splat(x, P, half, w, kappa, h, lo, (9, 9, 9), "box", er, sr)
    ijk = np.argwhere(np.ones((9, 9, 9), bool))
    c = index_to_center(ijk + lo, h) - x[0]
    dr = c @ er[0]
    d2t = np.einsum("ni,ij,nj->n", c, P[0], c) - (dr / s_r) ** 2
    b = 0.5 * h / np.abs(er[0]).max()
    pbox = np.array([0.5 * (erf((b - v) / (np.sqrt(2) * s_r)) + erf((b + v) / (np.sqrt(2) * s_r))) for v in dr])
    want = np.where((d2t <= kappa ** 2) & (np.abs(dr) <= b + kappa * s_r), np.exp(-0.5 * d2t) * pbox, 0.0)
    np.testing.assert_allclose(A[tuple(ijk.T)], want, rtol=1e-7, atol=1e-12)
    # the voxel containing the point gets at least half its weight, whatever the radial scale
    k = tuple(np.floor(x[0] / h).astype(np.int64) - lo)
    assert A[k] >= 0.5 * np.exp(-0.5 * 3 * (h / 2) ** 2 * np.linalg.eigvalsh(P[0]).max()) - 1e-12


def test_carve_extent_keeps_voxels_the_surface_clips():
    """Seen obliquely, a voxel whose box the wall clips is not carved (its centre is in front of the wall)."""
    W, h = 512, 0.07  # the walls (x = 2.0) lie off this lattice's planes
    depth = box_depth(W)
    lo = np.floor(LO / h).astype(np.int64) - 3
    shape = np.floor(HI / h).astype(np.int64) + 3 - lo + 1
    c = index_to_center(np.argwhere(np.ones(tuple(shape), bool)) + lo, h).reshape(tuple(shape) + (3,))
    gap = HI[0] - c[..., 0]  # distance in front of the +x wall (axis-aligned: box half-support h/2)
    inside = np.all((c[..., 1:] > LO[1:] + 0.3) & (c[..., 1:] < HI[1:] - 0.3), axis=-1) & (c[..., 0] > 0)
    clipped = inside & (gap > 0) & (gap < h / 2)
    F0, _ = carve(depth, np.eye(4), h, lo, shape, 0.01, 0.0, 2.0, 0.1, 12.0, extent=False)
    F1, O1 = carve(depth, np.eye(4), h, lo, shape, 0.01, 0.0, 2.0, 0.1, 12.0, extent=True)
    assert F0[clipped].any()  # the centre test carves some of them (oblique rays)
    assert not F1[clipped].any() and O1[clipped].all()
    clear = inside & (gap > h / 2 + 0.02) & (gap < 1.0) & (np.abs(c[..., 1]) < 0.5) & (np.abs(c[..., 2]) < 0.5)
    assert F1[clear].all()  # near head-on, a voxel wholly in front of the wall is still carved


def _floor_view(W, z0):
    """A camera at the origin (world +z up) over an infinite floor z = z0: closed-form radial depth."""
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # camera y (down) -> world -z
    dz = (ray_directions(W) @ T[:3, :3].T)[..., 2]
    with np.errstate(divide="ignore"):
        return np.where(dz < -0.1, z0 / dz, 0.0).astype(np.float32), T


def test_surfel_kernel_is_thin_on_a_plane_seen_at_grazing_incidence():
    """extent=surfel: a floor seen at 10-25 degrees of grazing (ranges 2.9-7.1 m, tangential widths up to
    2.2 h) gets support only in the voxel layer the plane clips (centres 1 cm from it); the ray-aligned
    box kernel spreads the same samples over several layers."""
    W, h, z0 = 256, 0.08, -1.23  # the clipped layer's centres are at z = -1.24, the next ones 7 and 9 cm off
    depth, T = _floor_view(W, z0)
    elev = np.arcsin(-z0 / np.where(depth > 0, depth, np.inf))
    depth = np.where((elev > np.radians(10)) & (elev < np.radians(25)), depth, 0.0).astype(np.float32)
    x, Pt, half, w, ax, sa, bb, surf = lift_surfels(depth, T, 2, 0.0025, 0.0025, 0.1, 12.0, 0.5, 8.0, 1.0, h,
                                                    1.5, 0.003, 0.25, 3.0)
    assert surf.all()  # the band's edge rows use one-sided differences: no fallback
    np.testing.assert_allclose(np.abs(ax[:, 2]), 1.0, atol=1e-9)  # normals of a plane: exact
    np.testing.assert_allclose(x[:, 2], z0, atol=1e-5)  # and the surfels lie on it
    for extent in ("surfel", "box"):
        d = geometry_delta(depth, T, GeometryParams(voxel_size=h, stride=2, extent=extent))
        c = index_to_center(unpack_keys(d.keys), h)
        A = d.channels["A"][:, 0]
        off = np.abs(c[:, 2] - z0)
        if extent == "surfel":
            assert (A[off < h / 2] > 0).sum() > 1000
            assert not np.any(A[off > h / 2] > 0)  # nothing even one layer off the plane
        else:
            assert A[off > 1.5 * h].sum() > 0.1 * A.sum()  # the ray-aligned kernel: thick at grazing incidence


def test_surfel_kernel_closed_form():
    """splat_axis: tangential Gaussian (rank-2 Pt) times P(plane through the voxel's support +-b along n)."""
    from math import erf

    h, kappa = 0.08, 1.5
    W, z0 = 256, -1.23
    depth, T = _floor_view(W, z0)
    x, Pt, half, w, ax, sa, bb, _ = lift_surfels(depth, T, 2, 0.0025, 0.0025, 0.1, 12.0, 0.5, 8.0, 1.0, h,
                                                 kappa, 0.003, 0.25, 3.0)
    p = int(np.argmin(np.abs(np.linalg.norm(x, axis=1) - 3.0)))  # a sample 3 m away, incidence ~66 deg
    np.testing.assert_allclose(Pt[p] @ ax[p], 0.0, atol=1e-9)  # no Gaussian along the normal
    np.testing.assert_allclose(bb[p], 0.5 * h * np.abs(ax[p]).sum())
    lo = np.floor((x[p] - half[p]) / h).astype(np.int64) - 1
    shape = np.floor((x[p] + half[p]) / h).astype(np.int64) + 2 - lo
    A = splat_axis(x[p:p + 1], Pt[p:p + 1], half[p:p + 1], w[p:p + 1], ax[p:p + 1], sa[p:p + 1], bb[p:p + 1],
                   kappa, h, lo, shape)
    ijk = np.argwhere(np.ones(tuple(shape), bool))
    c = index_to_center(ijk + lo, h) - x[p]
    dn = c @ ax[p]
    dt2 = np.einsum("ni,ij,nj->n", c, Pt[p], c)
    s, b = sa[p], bb[p]
    pn = np.array([0.5 * (erf((b - v) / (np.sqrt(2) * s)) + erf((b + v) / (np.sqrt(2) * s))) for v in dn])
    want = np.where((dt2 <= kappa ** 2) & (np.abs(dn) <= b + kappa * s), w[p] * np.exp(-0.5 * dt2) * pn, 0.0)
    np.testing.assert_allclose(A[tuple(ijk.T)], want, rtol=1e-7, atol=1e-12)
    # the support box of the kernel (half) holds every voxel it reaches: nothing is cut at its faces
    assert A[0].max() == 0 and A[-1].max() == 0 and A[:, 0].max() == 0 and A[:, :, -1].max() == 0
