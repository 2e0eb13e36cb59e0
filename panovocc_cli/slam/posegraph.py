"""Pose-graph optimisation of the keyframe graph: Open3D's global optimisation (batch) or GTSAM's iSAM2
(incremental), both solved in the first keyframe's frame.

An edge is ``(source, target, T_target_source, information, uncertain)``: keyframe indices, the (4, 4)
float64 registration of the source keyframe's points into the target's frame, and Open3D's (6, 6) information
matrix (``get_information_matrix_from_point_clouds``: rotation first, then translation, for a perturbation of
the registered points in the *target* frame). ``uncertain`` edges (loop closures, the refinement's pairs) may
be wrong; odometry edges are trusted.

* ``open3d`` (:func:`solve_open3d`): Levenberg-Marquardt over the whole graph each time; its line process
  weighs an uncertain edge by ``(mu / (mu + r^2))^2`` (``r^2 = e' Info e``, ``mu = max_corr^2`` times the
  graph's mean number of correspondences) and prunes it below 0.25. Open3D builds the normal equations as a
  dense matrix (its factorisation cubic in the number of keyframes).
* ``isam2`` (:class:`IncrementalGraph`): each keyframe adds its node and its edges as GTSAM
  ``BetweenFactorPose3`` factors to an ``ISAM2``, which re-eliminates only the part of the Bayes tree the new
  factors touch. The information matrix is moved to GTSAM's tangent (:func:`gtsam_information`), and an
  uncertain edge gets the robust Geman-McClure kernel with ``c^2 = max_corr^2 * N`` (``N`` its number of
  correspondences): the weight ``(c^2 / (c^2 + r^2))^2`` is Open3D's line process, with the edge's own ``N``
  in place of the graph's mean (a factor's noise model cannot change as the graph grows). The first keyframe
  carries a tight prior. :func:`solve_batch` is GTSAM's Levenberg-Marquardt over the same factors (the
  final refinement, which rebuilds every edge).

Single-threaded (the GTSAM wheel is built without TBB; Open3D runs on one thread here): the same graph gives
the same poses, bit for bit. Maths only: no files, no printing.
"""

from __future__ import annotations

import numpy as np

from .registration import open3d_threads

OPTIMISERS = ("isam2", "open3d")
PRIOR_SIGMA = 1e-6  # metres and radians: the first keyframe's prior (it is held where it is)
RIDGE = 1e-9  # relative floor of every edge's information (:func:`_factor`)


def gtsam_information(info: np.ndarray, T_target_source: np.ndarray) -> np.ndarray:
    """Open3D's edge information (6, 6) as the information of GTSAM's ``BetweenFactorPose3(target, source,
    T_target_source)`` error.

    Both order the tangent rotation first. Open3D's matrix is ``sum J' J`` over the correspondences for a
    perturbation ``exp(xi_t) T_target_source`` (points moved in the target frame); GTSAM's between error is
    ``Log(T_target_source^-1 T_target^-1 T_source)``, a perturbation ``T_target_source exp(xi_s)`` (in the
    source frame). ``xi_t = Ad(T_target_source) xi_s``, so the information is ``Ad' Info Ad`` (tested against
    the point residuals, tests/slam/test_posegraph.py)."""
    import gtsam

    Ad = gtsam.Pose3(np.asarray(T_target_source, np.float64)).AdjointMap()
    out = Ad.T @ np.asarray(info, np.float64) @ Ad
    return 0.5 * (out + out.T)


def _factor(source: int, target: int, T: np.ndarray, info: np.ndarray, uncertain: bool, max_corr_m: float):
    """GTSAM factor of one edge (module docstring): Gaussian with the edge's information; an uncertain edge
    robust (Geman-McClure, ``c^2 = max_corr_m^2 * N``, N = Open3D's correspondence count ``info[5, 5]``)."""
    import gtsam

    L = gtsam_information(info, T)
    # a floor of 1e-9 of the largest entry: an edge whose points constrain some direction not at all (a frame
    # seeing one plane) leaves the system solvable, as Open3D's damping does (no effect on the poses otherwise)
    L = L + RIDGE * max(float(np.abs(L).max()), 1.0) * np.eye(6)
    noise = gtsam.noiseModel.Gaussian.Information(L)
    if uncertain:
        c = max_corr_m * float(np.sqrt(max(float(info[5, 5]), 1.0)))
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.GemanMcClure.Create(c), noise)
    return gtsam.BetweenFactorPose3(target, source, gtsam.Pose3(np.asarray(T, np.float64)), noise)


def _prior():
    import gtsam

    return gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA))


def _anchored(values, n: int) -> np.ndarray:
    """(n, 4, 4) poses of the ``values`` relative to node 0's (node 0 exactly the identity: the first keyframe
    stays where it is, to rounding, whatever its prior let it drift)."""
    P0_inv = np.linalg.inv(values.atPose3(0).matrix())
    return np.stack([np.eye(4)] + [P0_inv @ values.atPose3(k).matrix() for k in range(1, n)])


def heading_factor(k: int, P: np.ndarray, up: np.ndarray, correction: float, sigma: float):
    """A prior on keyframe ``k``'s heading alone: its pose ``P`` (4, 4, in the first keyframe's frame) turned by
    ``correction`` radians about ``up`` (unit, same frame) is where it should point; the information is
    1 / ``sigma``^2 about that axis (in the keyframe's body frame, GTSAM's tangent), none in any other direction
    (:func:`_rotation_prior`)."""
    from .heading import rotation_about

    a = _body_up(P, up)
    return _rotation_prior(k, P, rotation_about(up, correction), np.outer(a, a) / sigma ** 2)


def level_factor(k: int, P: np.ndarray, tilt: np.ndarray, up: np.ndarray, sigma: float):
    """A prior on keyframe ``k``'s roll and pitch alone: its pose ``P`` (4, 4, in the first keyframe's frame)
    turned by the rotation vector ``tilt`` (radians, same frame; perpendicular to ``up``, :func:`.heading.
    tilt_between`) is where it should point; the information is 1 / ``sigma``^2 about every axis perpendicular to
    ``up`` (in the keyframe's body frame), none about ``up`` itself (:func:`_rotation_prior`)."""
    from ..geometry.drift import so3_exp

    a = _body_up(P, up)
    return _rotation_prior(k, P, so3_exp(np.asarray(tilt, np.float64)), (np.eye(3) - np.outer(a, a)) / sigma ** 2)


def _body_up(P: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``up`` (any length, the first keyframe's frame) as a unit vector in the body frame of the pose ``P``."""
    return np.asarray(P, np.float64)[:3, :3].T @ (np.asarray(up, np.float64) / np.linalg.norm(up))


def _rotation_prior(k: int, P: np.ndarray, turn: np.ndarray, info_rot: np.ndarray):
    """GTSAM prior on keyframe ``k``: its pose ``P`` with the rotation ``turn`` (3, 3) applied on the world side
    (the position kept) is where it should be; the information is ``info_rot`` (3, 3, the body-frame rotation
    tangent), none along a translation (a floor of 1e-9 of the largest entry, as :func:`_factor`'s), under a
    Huber kernel (a keyframe whose walls or floors were misread pulls no harder than a linear cost)."""
    import gtsam

    P = np.asarray(P, np.float64)
    target = np.eye(4)
    target[:3, :3] = turn @ P[:3, :3]
    target[:3, 3] = P[:3, 3]
    L = np.zeros((6, 6))
    L[:3, :3] = info_rot
    L += RIDGE * float(np.abs(L).max()) * np.eye(6)
    noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                           gtsam.noiseModel.Gaussian.Information(L))
    return gtsam.PriorFactorPose3(k, gtsam.Pose3(target), noise)


def solve_batch(poses: np.ndarray, edges: list, max_corr_m: float, priors: list | None = None) -> np.ndarray:
    """GTSAM Levenberg-Marquardt over the whole graph (the factors of :class:`IncrementalGraph`).

    poses : (n, 4, 4) float64, initial poses in the first keyframe's frame (``poses[0]`` the identity)
    edges : list of edges (module docstring); priors : GTSAM factors added as they are (the heading and level
    priors of :func:`heading_factor` and :func:`level_factor`); returns the optimised (n, 4, 4), ``[0]`` the
    identity."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(_prior())
    for e in edges:
        graph.add(_factor(*e, max_corr_m))
    for f in priors or ():
        graph.add(f)
    values = gtsam.Values()
    for k, P in enumerate(poses):
        values.insert(k, gtsam.Pose3(np.asarray(P, np.float64)))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    params.setMaxIterations(100)
    return _anchored(gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize(), len(poses))


class IncrementalGraph:
    """The keyframe graph in GTSAM's iSAM2 (module docstring), grown node by node.

    Parameters
    ----------
    max_corr_m : the robust kernel's distance (module docstring)
    relinearize : iSAM2's relinearisation threshold (radians and metres of a variable's update)
    iterations : at most this many further iSAM2 updates in :meth:`estimate` (until none relinearises)
    skip : the updates of :meth:`add` consider relinearising every ``skip``-th time (iSAM2's
        ``relinearizeSkip``); :meth:`estimate`'s updates always do. Each relinearisation re-eliminates the
        cliques of every variable past the threshold, which after a few loop closures is most of the graph:
        on the building's first 1,300 keyframes an add took a median 8-14 ms late in the walk with 1 and
        0.3 ms with 10, the estimates within 0.1 mm of each other (0.6 um at the end)
    """

    def __init__(self, max_corr_m: float, relinearize: float = 1e-4, iterations: int = 10, skip: int = 10):
        import gtsam

        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize)
        params.relinearizeSkip = max(int(skip), 1)
        self.isam = gtsam.ISAM2(params)
        self.max_corr_m, self.iterations = float(max_corr_m), int(iterations)
        self.nodes = 0

    def add(self, poses: list, edges: list) -> None:
        """Add nodes ``self.nodes, self.nodes + 1, ...`` with initial ``poses`` ((4, 4) float64 each, in the first
        keyframe's frame) and ``edges`` (between any nodes added so far), then one iSAM2 update."""
        import gtsam

        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if self.nodes == 0 and poses:
            graph.add(_prior())
        for P in poses:
            values.insert(self.nodes, gtsam.Pose3(np.asarray(P, np.float64)))
            self.nodes += 1
        for e in edges:
            graph.add(_factor(*e, self.max_corr_m))
        if graph.size() or values.size():
            self.isam.update(graph, values)

    def estimate(self, converge: bool = True) -> np.ndarray:
        """(nodes, 4, 4) current estimate relative to node 0; ``converge``: first further iSAM2 updates (at most
        ``iterations``, each relinearising whatever is past the threshold whatever ``skip``) until no variable
        is relinearised (a loop closure's large correction needs several Gauss-Newton steps; one update takes
        one)."""
        if converge:
            for _ in range(self.iterations):
                if self.isam.update(force_relinearize=True).getVariablesRelinearized() == 0:
                    break
        return _anchored(self.isam.calculateEstimate(), self.nodes)


def solve_open3d(poses: np.ndarray, edges: list, max_corr_m: float) -> np.ndarray:
    """Open3D's ``global_optimization`` (Levenberg-Marquardt, line process, reference node 0) of the graph;
    ``poses`` and the result as in :func:`solve_batch` (Open3D's own information matrices, unconverted)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    g = reg.PoseGraph()
    for P in poses:
        g.nodes.append(reg.PoseGraphNode(np.asarray(P, np.float64)))
    for s, t, T, info, uncertain in edges:
        g.edges.append(reg.PoseGraphEdge(s, t, T, info, uncertain))
    opt = reg.GlobalOptimizationOption(max_correspondence_distance=max_corr_m, edge_prune_threshold=0.25,
                                       preference_loop_closure=1.0, reference_node=0)
    with open3d_threads(1):  # the same graph gives the same poses, bit for bit
        reg.global_optimization(g, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), opt)
    out = np.stack([np.asarray(node.pose, np.float64) for node in g.nodes])
    out[0] = poses[0]
    return out
