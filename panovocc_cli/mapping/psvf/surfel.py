"""The surfel lift: strided samples lifted to kernels that lie on the observed surface.

Per strided sample: the footprint-fitted depth (:mod:`.footprint`), the frame's radial noise at its
range (:mod:`.noise_fit`), the local normal from the neighbouring samples, and from them the kernel:
a Gaussian in the surface plane (the ERP footprint carried onto the plane) with a thin axis along the
normal; depth edges and corners keep the ray-aligned kernel. The splat is :func:`.splat.splat_axis`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...geometry.erp import cam_frame, cam_point, trig_tables
from .footprint import _block_depths
from .noise_fit import FIT_SUB, SIGMA_FLOOR, _raw_residuals, interp1, radial_noise_fit
from .rays import SIGMA_MIN

@nb.njit(cache=True, parallel=True)
def _lift_surfel(depth, stride, R, t, alpha, beta, min_range, max_range, w_pole, r_half, c_norm, h, kappa,
                 n_floor, c_min, disc_k, fit, tol_abs, fit_r, fit_s, radial_fit, block, rs, bcnt, sphi, cphi, sth, cth):
    """Surfel kernels of the strided valid pixels (see :func:`lift_surfels`); sphi .. cth from
    :func:`~panovocc_cli.geometry.erp.trig_tables`."""
    H, W = depth.shape
    dth = 2.0 * np.pi / W
    dph = np.pi / H
    s0 = stride // 2
    rows = np.arange(s0, H, stride)
    cols = np.arange(s0, W, stride)
    # per-row offsets into the outputs (rows run in parallel; the order is the serial one)
    start = np.zeros(len(rows) + 1, np.int64)
    for a in range(len(rows)):
        c = 0
        for u in cols:
            r = depth[rows[a], u]
            if r > 0 and r >= min_range and r <= max_range:
                c += 1
        start[a + 1] = start[a] + c
    n = start[-1]
    ncols = len(cols)
    x = np.empty((n, 3))
    Pt = np.empty((n, 3, 3))  # every entry is written below
    half = np.empty((n, 3))
    w = np.empty(n)
    ax = np.empty((n, 3))
    sa = np.empty(n)
    bb = np.empty(n)
    surf = np.zeros(n, np.uint8)
    k = stride  # normal from the neighbouring samples (+-stride pixels): a baseline robust to depth noise
    for a in nb.prange(len(rows)):
        v = rows[a]
        m = start[a]
        Ec = np.empty((3, 3))
        E = np.empty((3, 3))
        nrm = np.zeros(3)
        used = np.zeros((4, 3))
        tang = np.zeros((2, 3))
        q0 = np.zeros(3)
        q1 = np.zeros(3)
        t1 = np.zeros(3)
        t2 = np.zeros(3)
        w1 = np.zeros(3)
        sp, cp = sphi[v], cphi[v]
        for bi in range(ncols):
            u = cols[bi]
            r = np.float64(depth[v, u])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            mself = 1.0
            if block:  # the footprint-denoised depth
                mself = np.float64(bcnt[a, bi])
                r = rs[a, bi]
            st, ct = sth[u], cth[u]
            cam_frame(sp, cp, st, ct, Ec)
            for i in range(3):
                for j in range(3):
                    E[i, j] = R[i, 0] * Ec[0, j] + R[i, 1] * Ec[1, j] + R[i, 2] * Ec[2, j]
            s_th = max(r * abs(cp) * dth * stride, SIGMA_MIN)
            s_ph = max(r * dph * stride, SIGMA_MIN)
            sr_prior = max(alpha * r + beta, SIGMA_MIN)
            sr = max(interp1(r, fit_r, fit_s), SIGMA_MIN) if radial_fit else sr_prior
            pc0, pc1, pc2 = r * Ec[0, 2], r * Ec[1, 2], r * Ec[2, 2]
            for i in range(3):
                x[m, i] = R[i, 0] * pc0 + R[i, 1] * pc1 + R[i, 2] * pc2 + t[i]
            w[m] = c_norm * (1.0 - (1.0 - w_pole) * sp * sp) / (1.0 + r / r_half)
            # ---- local surface normal from the neighbouring samples (camera frame) ----
            # per image direction: the central difference where the depth is smooth (second difference
            # within tol), else the one-sided difference to the valid neighbour nearer in depth
            tol = disc_k * sr_prior + tol_abs
            nused = 0
            msum = mself
            nfit = mself  # depth readings averaged in the surfel's position
            ok = True
            for dirn in range(2):
                vv0, uu0, vv1, uu1 = v, (u - k) % W, v, (u + k) % W  # longitude: left, right
                if dirn == 1:
                    vv0, uu0, vv1, uu1 = v - k, u, v + k, u  # latitude: up, down
                r0 = depth[vv0, uu0] if 0 <= vv0 < H else np.float32(0.0)
                r1 = depth[vv1, uu1] if 0 <= vv1 < H else np.float32(0.0)
                use0 = r0 > 0
                use1 = r1 > 0
                # block neighbours: the samples a row / column of samples away
                ai = np.int64(a)
                ba0, bb0, ba1, bb1 = ai, (bi - 1) % ncols, ai, (bi + 1) % ncols
                if dirn == 1:
                    ba0, bb0, ba1, bb1 = ai - 1, bi, ai + 1, bi
                m0 = m1 = 1.0
                if block:
                    m0 = np.float64(bcnt[ba0, bb0]) if 0 <= ba0 < len(rows) else 0.0
                    m1 = np.float64(bcnt[ba1, bb1]) if 0 <= ba1 < len(rows) else 0.0
                    r0 = rs[ba0, bb0] if m0 > 0 else 0.0
                    r1 = rs[ba1, bb1] if m1 > 0 else 0.0
                    use0 = r0 > 0
                    use1 = r1 > 0
                if not (use0 or use1):
                    ok = False
                    break
                q0[0], q0[1], q0[2] = pc0, pc1, pc2
                q1[0], q1[1], q1[2] = pc0, pc1, pc2
                for side in range(2):
                    if (use0 if side == 0 else use1):
                        vq, uq, rq = (vv0, uu0, r0) if side == 0 else (vv1, uu1, r1)
                        pq0, pq1, pq2 = cam_point(rq, sphi[vq], cphi[vq], sth[uq], cth[uq])
                        msum += m0 if side == 0 else m1
                        if side == 0:
                            q0[0], q0[1], q0[2] = pq0, pq1, pq2
                        else:
                            q1[0], q1[1], q1[2] = pq0, pq1, pq2
                        used[nused, 0], used[nused, 1], used[nused, 2] = pq0, pq1, pq2
                        nused += 1
                if use0 and use1:
                    # smooth surface: the sample lies within tol of the line through its two neighbours
                    l0, l1, l2 = q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2]
                    e0, e1, e2 = pc0 - q0[0], pc1 - q0[1], pc2 - q0[2]
                    x0, x1, x2 = e1 * l2 - e2 * l1, e2 * l0 - e0 * l2, e0 * l1 - e1 * l0
                    if x0 * x0 + x1 * x1 + x2 * x2 > (tol * tol) * (l0 * l0 + l1 * l1 + l2 * l2):
                        ok = False  # a depth edge or a corner: the ray-aligned kernel
                        break
                for i in range(3):
                    tang[dirn, i] = q1[i] - q0[i]
            if ok:
                a0, a1, a2 = tang[0, 0], tang[0, 1], tang[0, 2]
                b0, b1, b2 = tang[1, 0], tang[1, 1], tang[1, 2]
                nc0, nc1, nc2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
                nn = np.sqrt(nc0 * nc0 + nc1 * nc1 + nc2 * nc2)
                if nn <= 0.0:
                    ok = False
                else:
                    for i in range(3):
                        nrm[i] = (R[i, 0] * nc0 + R[i, 1] * nc1 + R[i, 2] * nc2) / nn
                    if fit:
                        # centre the surfel on the plane through the centroid of the sample and the
                        # neighbours used: move x along n by the centroid's offset
                        off = 0.0
                        for q in range(nused):
                            off += (nc0 * (used[q, 0] - pc0) + nc1 * (used[q, 1] - pc1) + nc2 * (used[q, 2] - pc2)) / nn
                        off /= nused + 1.0
                        for i in range(3):
                            x[m, i] += off * nrm[i]
                        nfit = msum
            if ok:
                d0, d1, d2 = E[0, 2], E[1, 2], E[2, 2]
                cosi = nrm[0] * d0 + nrm[1] * d1 + nrm[2] * d2
                if cosi > 0:
                    nrm[0], nrm[1], nrm[2] = -nrm[0], -nrm[1], -nrm[2]
                    cosi = -cosi
                c = abs(cosi)
                # in-plane direction of the ray t1, and t2 = n x t1 (perpendicular to the ray too)
                u0, u1, u2 = d0 + c * nrm[0], d1 + c * nrm[1], d2 + c * nrm[2]  # d - (n.d) n
                un = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
                if un < 1e-9:
                    t1[0], t1[1], t1[2] = E[0, 0], E[1, 0], E[2, 0]
                else:
                    t1[0], t1[1], t1[2] = u0 / un, u1 / un, u2 / un
                t2[0] = nrm[1] * t1[2] - nrm[2] * t1[1]
                t2[1] = nrm[2] * t1[0] - nrm[0] * t1[2]
                t2[2] = nrm[0] * t1[1] - nrm[1] * t1[0]
                # w1 = t2 x d: the direction perpendicular to the ray whose footprint stretches onto t1
                w1[0], w1[1], w1[2] = t2[1] * d2 - t2[2] * d1, t2[2] * d0 - t2[0] * d2, t2[0] * d1 - t2[1] * d0
                g1t = w1[0] * E[0, 0] + w1[1] * E[1, 0] + w1[2] * E[2, 0]
                g1p = w1[0] * E[0, 1] + w1[1] * E[1, 1] + w1[2] * E[2, 1]
                g2t = t2[0] * E[0, 0] + t2[1] * E[1, 0] + t2[2] * E[2, 0]
                g2p = t2[0] * E[0, 1] + t2[1] * E[1, 1] + t2[2] * E[2, 1]
                vt, vp = s_th * s_th, s_ph * s_ph
                cs = max(c, c_min)
                q11 = (vt * g1t * g1t + vp * g1p * g1p) / (cs * cs)
                q12 = (vt * g1t * g2t + vp * g1p * g2p) / cs
                q22 = vt * g2t * g2t + vp * g2p * g2p
                det = q11 * q22 - q12 * q12
                i11, i12, i22 = q22 / det, -q12 / det, q11 / det
                sn = sr * c / np.sqrt(nfit) + n_floor
                b = 0.5 * h * (abs(nrm[0]) + abs(nrm[1]) + abs(nrm[2]))
                for i in range(3):
                    ax[m, i] = nrm[i]
                    for j in range(3):
                        Pt[m, i, j] = (i11 * t1[i] * t1[j] + i12 * (t1[i] * t2[j] + t2[i] * t1[j])
                                       + i22 * t2[i] * t2[j])
                    cov_ii = q11 * t1[i] * t1[i] + 2.0 * q12 * t1[i] * t2[i] + q22 * t2[i] * t2[i]
                    half[m, i] = kappa * np.sqrt(cov_ii) + (b + kappa * sn) * abs(nrm[i])
                sa[m] = sn
                bb[m] = b
                surf[m] = 1
            else:
                # ray-aligned fallback (the "box" kernel): tangential Gaussian, chord probability along the ray
                vt, vp = s_th * s_th, s_ph * s_ph
                b = 0.5 * h / max(abs(E[0, 2]), abs(E[1, 2]), abs(E[2, 2]))
                for i in range(3):
                    ax[m, i] = E[i, 2]
                    for j in range(3):
                        Pt[m, i, j] = E[i, 0] * E[j, 0] / vt + E[i, 1] * E[j, 1] / vp
                    half[m, i] = kappa * np.sqrt(E[i, 0] ** 2 * vt + E[i, 1] ** 2 * vp) + (b + kappa * sr) * abs(E[i, 2])
                sa[m] = sr
                bb[m] = b
            m += 1
    return x, Pt, half, w, ax, sa, bb, surf


def lift_surfels(depth: np.ndarray, T_world_cam: np.ndarray, stride: int, alpha: float, beta: float,
                 min_range: float, max_range: float, w_pole: float, r_half: float, c_norm: float,
                 voxel_size: float, kappa: float, n_floor: float, c_min: float, disc_k: float,
                 fit: bool = True, tol_abs: float = 0.0, radial_fit: bool = False, block: bool = False,
                 block_k: float = 2.0, block_abs: float = 0.0005, block_sel: float = 0.05,
                 block_inverse: bool = False):
    """Surfel-aligned kernels of the strided valid pixels (``GeometryParams.extent = "surfel"``).

    The local surface normal n of each sample comes from its neighbouring samples (+-stride pixels,
    longitude wraps): per image axis the central difference, or the one-sided difference where one
    neighbour is invalid or outside the image. The kernel is a Gaussian within the surface plane whose
    covariance is the ERP pixel footprint (``r |cos phi| dtheta``, ``r dphi``, dtheta, dphi at the
    stride) projected along the ray onto the plane (stretched by ``1 / max(|cos i|, c_min)`` along the
    ray's in-plane direction, i = incidence), times the probability that the plane, displaced along n
    with scale ``s_n = sigma_r |cos i| / sqrt(m) + n_floor``, passes through the voxel's box
    (half-support ``b = (h / 2) |n|_1`` along n); ``sigma_r`` is the radial depth noise at the sample's
    range: ``alpha r + beta``, or with ``radial_fit`` the noise fitted to this frame's own depth
    (:func:`radial_noise_fit`). A sample farther than ``disc_k (alpha r + beta) + tol_abs`` from the
    line through its two neighbours (per image axis) marks a depth edge or a corner; there, and where
    both neighbours of an axis are invalid, the sample keeps the ray-aligned ``box`` kernel (axis = ray,
    b = the voxel's chord half-length, scale sigma_r).

    With ``block`` each sample stands for its whole s x s footprint: its depth is the value at the
    sample pixel of a plane fitted by least squares to the footprint's pixels on its surface
    (:func:`_block_depths`; accepted where the fit's residual is within ``block_k sigma_r + block_abs``,
    else the raw depth), normals come from the neighbours' fitted depths, and ``m`` is the number of
    pixels fitted: the surfel's offset averages ~s^2 readings instead of one. With ``fit`` the surfel
    is also centred on the plane through the sample and the neighbours used (moved along n by their
    centroid's offset; m counts every reading in that fit). Defaults: block on, fit off.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid; T_world_cam : (4, 4) float64

    Returns
    -------
    x_world : (n, 3) float64 metres; Pt : (n, 3, 3) float64 1/m^2, tangential inverse covariance
    (rank 2, zero along the axis); half : (n, 3) float64 metres, half-extents of the kernel's support
    on each world axis; w : (n,) float64; axis : (n, 3) float64 unit (normal or ray), world;
    s_axis : (n,) float64 metres; b : (n,) float64 metres; surfel : (n,) uint8, 1 where the normal was used
    """
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    R = np.ascontiguousarray(T_world_cam[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(T_world_cam[:3, 3], dtype=np.float64)
    H, W = depth.shape
    tables = trig_tables(H, W)
    fit_r, fit_s = np.zeros(1), np.full(1, SIGMA_FLOOR)
    if radial_fit or block:
        if radial_fit:
            rr, res2, cinc = _raw_residuals(depth, int(stride), FIT_SUB, float(min_range), float(max_range), *tables)
            fit_r, fit_s = radial_noise_fit(rr.ravel(), res2.ravel(), cinc.ravel(), min_range, max_range)
        else:  # the block tolerance from the noise model alpha r + beta
            fit_r = np.array([0.0, max_range])
            fit_s = np.array([beta, alpha * max_range + beta])
    if block:
        rs, bcnt = _block_depths(depth, int(stride), float(min_range), float(max_range), fit_r, fit_s,
                                 float(block_k), float(block_abs), float(block_sel), bool(block_inverse))
    else:
        rs, bcnt = np.zeros((1, 1)), np.zeros((1, 1), np.int64)
    return _lift_surfel(depth, int(stride), R, t, float(alpha), float(beta), float(min_range), float(max_range),
                        float(w_pole), float(r_half), float(c_norm), float(voxel_size), float(kappa),
                        float(n_floor), float(c_min), float(disc_k), bool(fit), float(tol_abs), fit_r, fit_s,
                        bool(radial_fit), bool(block), rs, bcnt, *tables)


def surfels_for(depth: np.ndarray, T_world_cam: np.ndarray, p, c_norm: float):
    """:func:`lift_surfels` with the parameters of a :class:`~.params.GeometryParams` ``p``."""
    return lift_surfels(depth, T_world_cam, p.stride, p.alpha, p.beta, p.min_range, p.max_range, p.w_pole,
                        p.r_half, c_norm, p.voxel_size, p.kappa, p.n_floor, p.c_min, p.disc_k, p.surfel_fit,
                        p.edge_abs, p.radial == "fit", p.block, p.block_k, p.block_abs, p.block_sel,
                        p.block_inverse)

