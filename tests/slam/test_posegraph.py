"""slam/posegraph.py: the iSAM2 keyframe graph (issue 22: incremental optimisation).

The information matrix's tangent (checked against the point residuals it summarises), iSAM2 equal to GTSAM's
batch Levenberg-Marquardt on a noisy graph with a false loop edge that the robust kernel rejects, the same
bytes twice, and the same relative poses in a world far from the origin."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from panovocc_cli.geometry.drift import so3_exp  # noqa: E402
from panovocc_cli.io.sequence import Sequence  # noqa: E402
from panovocc_cli.slam import SlamParams, Tracker  # noqa: E402
from panovocc_cli.slam.posegraph import IncrementalGraph, gtsam_information, solve_batch  # noqa: E402
from panovocc_cli.slam.registration import Cloud, Registration  # noqa: E402


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = so3_exp(rotvec)
    T[:3, 3] = t
    return T


def _room_points(rng, n=400) -> np.ndarray:
    """Points on the walls, floor and ceiling of a 4 x 3 x 2.5 m box around the camera (camera frame)."""
    p = rng.uniform([-2.0, -1.25, -1.5], [2.0, 1.25, 1.5], size=(n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1, 1) * np.array([2.0, 1.25, 1.5])[axis]
    return p


def test_information_is_gtsams_tangent_rotation_first_in_the_source_frame():
    """Open3D's matrix sums the correspondences' Jacobians for a perturbation of the points in the target
    frame; GTSAM's BetweenFactorPose3 error perturbs the relative pose on the right. The converted matrix must
    be sum J'J of the point residuals X exp(xi) p - X p over GTSAM's own exponential (xi = rotation, then
    translation), computed here by finite differences: a translation-first ordering, or Open3D's matrix
    unconverted, differs by far more than the tolerance."""
    rng = np.random.default_rng(0)
    src = _room_points(rng)
    X = _pose([0.2, -0.5, 0.3], [0.7, -0.4, 0.25])
    tgt = src @ X[:3, :3].T + X[:3, 3]
    info = Registration.information(Cloud(tgt), Cloud(src), X, 0.1)
    assert info[5, 5] == len(src)  # every point found its twin
    h = 1e-6
    J = np.zeros((len(src), 3, 6))
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        Tp = X @ gtsam.Pose3.Expmap(xi).matrix()
        Tm = X @ gtsam.Pose3.Expmap(-xi).matrix()
        J[:, :, k] = ((src @ Tp[:3, :3].T + Tp[:3, 3]) - (src @ Tm[:3, :3].T + Tm[:3, 3])) / (2 * h)
    expected = np.einsum("nik,nil->kl", J, J)
    got = gtsam_information(info, X)
    scale = np.abs(expected).max()
    assert np.abs(got - expected).max() < 1e-6 * scale
    swapped = got[np.ix_([3, 4, 5, 0, 1, 2], [3, 4, 5, 0, 1, 2])]
    assert np.abs(swapped - expected).max() > 0.1 * scale
    assert np.abs(info - expected).max() > 0.1 * scale


def _graph(rng):
    """A loop of 24 keyframes on a 3 m circle (true poses), odometry edges with 2 mm / 0.1 degree noise, loop
    edges between the two laps' neighbours, and one false loop edge 0.6 m off."""
    n = 24
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    truth = np.stack([_pose([0.0, 0.0, t], [3 * np.cos(t), 3 * np.sin(t), 0.0]) for t in a])
    truth = np.linalg.inv(truth[0]) @ truth  # the first keyframe's frame
    info = Registration.information(Cloud(_room_points(rng, 300)), Cloud(_room_points(rng, 300)), np.eye(4), 10.0)

    def meas(s, t):
        T = np.linalg.inv(truth[t]) @ truth[s]
        return T @ _pose(rng.normal(0, np.radians(0.1), 3), rng.normal(0, 0.002, 3))

    edges = [(k, k - 1, meas(k, k - 1), info, False) for k in range(1, n)]
    edges += [(k, k - 12, meas(k, k - 12), info, True) for k in range(12, n, 3)]
    edges += [(0 + n - 1, 0, meas(n - 1, 0), info, True)]
    false = meas(20, 5) @ _pose([0.0, 0.0, 0.2], [0.6, 0.0, 0.0])
    edges.append((20, 5, false, info, True))
    return truth, edges


def _incremental(edges, n, odometry_poses, skip=None):
    p = SlamParams()
    g = IncrementalGraph(0.1, p.isam_relinearize, p.isam_iterations, p.isam_skip if skip is None else skip)
    for k in range(n):
        g.add([odometry_poses[k]], [e for e in edges if max(e[0], e[1]) == k])
    return g.estimate()


def _chain(edges, n):
    P = [np.eye(4)]
    for s, t, T, _, unc in edges:
        if not unc and s == len(P):
            P.append(P[t] @ T)
    return np.stack(P[:n])


def test_isam2_read_back_converges_whatever_the_relinearisation_skip():
    """A keyframe's update relinearises every ``isam_skip``-th time only (cheap late in a long walk); the
    read-back's updates always may, so the estimate is the batch solution with any skip, a forced
    relinearisation's result: without it (skip 10, no force) the first read-back would stop short."""
    rng = np.random.default_rng(1)
    truth, edges = _graph(rng)
    n = len(truth)
    init = _chain(edges, n)
    batch = solve_batch(init, edges, 0.1)
    for skip in (1, 10, 1000):
        assert np.abs(_incremental(edges, n, init, skip) - batch).max() < 1e-6, skip
    assert SlamParams().isam_skip > 1


def test_isam2_equals_batch_and_rejects_a_false_loop():
    rng = np.random.default_rng(1)
    truth, edges = _graph(rng)
    n = len(truth)
    init = _chain(edges, n)
    inc = _incremental(edges, n, init)
    batch = solve_batch(init, edges, 0.1)
    assert np.abs(inc - batch).max() < 1e-6
    assert np.array_equal(inc[0], np.eye(4))
    # rejected: the poses are those of the graph without the false edge (to half a millimetre: Geman-McClure leaves it a small weight), whereas
    # trusted it pulls the loop apart by centimetres
    clean = solve_batch(init, [e for e in edges if (e[0], e[1]) != (20, 5)], 0.1)
    moved = np.linalg.norm(inc[:, :3, 3] - clean[:, :3, 3], axis=1).max()
    assert moved < 5e-4, moved
    trusted = [(s, t, T, i, unc and (s, t) != (20, 5)) for s, t, T, i, unc in edges]
    bad = solve_batch(init, trusted, 0.1)
    assert np.linalg.norm(bad[:, :3, 3] - clean[:, :3, 3], axis=1).max() > 0.02
    assert np.linalg.norm(clean[:, :3, 3] - truth[:, :3, 3], axis=1).max() < 0.02  # the noise's own error
    # the same graph, the same bytes
    assert np.array_equal(inc, _incremental(edges, n, init))


@pytest.mark.parametrize("optimiser", ["isam2", "open3d"])
def test_far_from_origin_gives_the_same_relative_poses(loop_seq, optimiser):
    """Every loop edge optimised at once, over two laps: the graph is solved in the first keyframe's frame, so a
    world 100 km away and turned gives the same poses relative to the first, to rounding."""
    seq = Sequence(loop_seq)
    kw = dict(optimiser=optimiser, loop_min_gap=2, loop_optimise_m=0.0, loop_optimise_deg=0.0, refine=False)
    far = _pose([0.3, -0.2, 2.0], [1e5, -2e5, 30.0]) @ seq.poses[0]
    out = []
    for first in (seq.poses[0], far):
        tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**kw), T_world_first=first)
        for i in range(40):
            tr.track(i, seq.depth(i))
        assert tr.optimisations >= 2
        C = tr.committed()
        out.append(np.stack([np.linalg.inv(C[0]) @ C[i] for i in sorted(C)]))
    assert np.abs(out[0] - out[1]).max() < 1e-6


def test_an_edge_blind_in_one_direction_leaves_the_graph_solvable(monkeypatch):
    """A keyframe pair that sees one plane constrains nothing along it: Open3D's damping copes, and so must
    iSAM2 (GTSAM refuses an indeterminate system without the information's floor, ``posegraph.RIDGE``)."""
    import panovocc_cli.slam.posegraph as pg

    T = _pose([0.0, 0.1, 0.0], [0.4, 0.0, 0.0])
    blind = np.diag([100.0, 100.0, 100.0, 100.0, 100.0, 0.0])  # nothing along z
    for solve in (lambda: _incremental([(1, 0, T, blind, False)], 2, np.stack([np.eye(4), T])),
                  lambda: solve_batch(np.stack([np.eye(4), T]), [(1, 0, T, blind, False)], 0.1)):
        assert np.allclose(solve()[1], T, atol=1e-9)
    monkeypatch.setattr(pg, "RIDGE", 0.0)
    with pytest.raises(RuntimeError):
        _incremental([(1, 0, T, blind, False)], 2, np.stack([np.eye(4), T]))
