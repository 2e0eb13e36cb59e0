"""Point clouds of ERP depth frames and their rigid registration (small_gicp's GICP or Open3D's ICP).

Both backends take the same prepared clouds and answer the same question: the transform
``T_target_source`` (4, 4) float64 that maps source points (metres, source camera frame) into the
target's frame, with the fraction of source points that found a correspondence (``fitness``).

* ``small_gicp`` (default): ``small_gicp.preprocess_points`` (voxel downsampling, covariances, KD-tree)
  and ``small_gicp.align(..., registration_type="GICP")``, single-threaded so that the same frames
  give the same bytes. Measured the faster of the two here (docs/slam.md, "Backend").
* ``open3d``: ``voxel_down_sample``, ``estimate_normals`` and ``registration_icp`` with point-to-plane
  estimation.

Pose-graph edge information matrices are Open3D's ``get_information_matrix_from_point_clouds`` for both backends:
Open3D's own call, or, within :data:`HASH_MAX_CORR_M` (the loops', the refinement's), the same matrix bit for bit
from a hash of the target's points (:mod:`.information`: 2.5x faster at 0.1 m, as Open3D builds a KD-tree a call).
Maths only: no files, no printing.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np

BACKENDS = ("small_gicp", "open3d")
NEIGHBORS = 10  # small_gicp: neighbours of a point's covariance
HASH_MAX_CORR_M = 0.2  # information matrices within this distance from the hash (at 0.1 m voxels: 1.4 against 3.3 ms
#                        a pair at 0.1 m, 2.0 against 3.2 at 0.2, equal at 0.3, 7.3 against 3.4 at 0.5)


def erp_points(depth: np.ndarray, rays: np.ndarray, stride: int, min_range: float, max_range: float) -> np.ndarray:
    """Camera-frame points of an ERP depth map, every ``stride``-th pixel in each direction.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid
    rays : (H, W, 3) float64, unit rays of the pixels (camera frame, OpenCV axes)
    stride : int >= 1
    min_range, max_range : metres; depths outside ``(min_range, max_range)`` are dropped

    Returns
    -------
    points_cam : (n, 3) float64, metres
    """
    d = np.asarray(depth)[::stride, ::stride]
    r = rays[::stride, ::stride]
    m = np.isfinite(d) & (d > min_range) & (d < max_range)
    return r[m] * d[m].astype(np.float64)[:, None]


@dataclass
class Cloud:
    """A frame's cloud prepared for registration (downsampled, with the backend's structures).

    points : (n, 3) float32, metres, camera frame, after downsampling: the registration structures are
        built from these values (widened to float64), so a compacted cloud is restored to the same bytes
        at 12 bytes a point held (the keyframe store)
    """

    points: np.ndarray
    handle: object = field(repr=False, default=None)  # backend data (small_gicp cloud + tree, or Open3D cloud)
    _o3d: object = field(repr=False, default=None)    # Open3D cloud for information matrices (lazy)

    def __len__(self) -> int:
        return len(self.points)

    def structure_bytes(self) -> int:
        """Bytes of the registration structures' arrays (small_gicp: its points (n, 4) and covariances (n, 4, 4),
        Open3D: points and normals (n, 3), all float64; KD-trees not counted); 0 when compacted. Counted from
        the points held (reading the backend's arrays copies them; tests/slam/test_tracker.py compares)."""
        if self.handle is None:
            return 0
        return len(self) * (8 * (4 + 16) if isinstance(self.handle, tuple) else 8 * (3 + 3))

    def compact(self) -> None:
        """Drop the registration structures, keep the points (:meth:`Registration.restore` rebuilds them)."""
        self.handle = self._o3d = None

    def o3d(self):
        """The cloud as an ``open3d.geometry.PointCloud`` (built once)."""
        if self._o3d is None:
            import open3d as o3d

            self._o3d = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points.astype(np.float64)))
        return self._o3d


@dataclass
class RegResult:
    """One registration: ``T_target_source`` (4, 4) float64, fitness in [0, 1] (inlier fraction of the
    source), converged."""

    T_target_source: np.ndarray
    fitness: float
    converged: bool


class Registration:
    """A registration backend with its parameters.

    Parameters
    ----------
    backend : ``small_gicp`` | ``open3d``
    voxel_m : downsampling voxel edge, metres
    max_iterations : iteration cap of one alignment
    threads : worker threads (1 = deterministic bytes)
    """

    def __init__(self, backend: str = "small_gicp", voxel_m: float = 0.1, max_iterations: int = 30, threads: int = 1):
        if backend not in BACKENDS:
            raise ValueError(f"registration backend must be one of {BACKENDS}, got {backend!r}")
        self.backend, self.voxel_m, self.max_iterations, self.threads = backend, float(voxel_m), int(max_iterations), int(threads)

    def prepare(self, points_cam: np.ndarray) -> Cloud:
        """Downsample ``points_cam`` (n, 3) float64 metres (kept as float32) and build what :meth:`align`
        needs from the kept points (:meth:`restore`)."""
        pts = np.ascontiguousarray(points_cam, np.float64)
        if self.backend == "small_gicp":
            import small_gicp

            if len(pts) == 0:
                return Cloud(np.zeros((0, 3), np.float32))
            down = small_gicp.voxelgrid_sampling(pts, self.voxel_m, num_threads=self.threads)
            cloud = Cloud(np.asarray(down.points())[:, :3].astype(np.float32))
        else:
            import open3d as o3d

            with open3d_threads(self.threads):
                pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(self.voxel_m)
            cloud = Cloud(np.asarray(pc.points).astype(np.float32))
        self.restore(cloud)
        return cloud

    def restore(self, cloud: Cloud) -> bool:
        """Rebuild the structures of a compacted ``cloud`` from its (already downsampled) points: the same
        bytes as :meth:`prepare` built (small_gicp: its KD-tree and covariances of the same points). True when
        it built them; False for a cloud that has them already or has no points."""
        if cloud.handle is not None or len(cloud) == 0:
            return False
        if self.backend == "small_gicp":
            import small_gicp

            pc = small_gicp.PointCloud(cloud.points.astype(np.float64))
            tree = small_gicp.KdTree(pc, num_threads=self.threads)
            small_gicp.estimate_covariances(pc, tree, num_neighbors=NEIGHBORS, num_threads=self.threads)
            cloud.handle = (pc, tree)
            return True
        import open3d as o3d

        with open3d_threads(self.threads):
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points.astype(np.float64)))
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * self.voxel_m, max_nn=20))
        cloud.handle = cloud._o3d = pc
        return True

    def align(self, target: Cloud, source: Cloud, init_T_target_source: np.ndarray, max_corr_m: float) -> RegResult:
        """Register ``source`` onto ``target`` from the initial guess (4, 4); ``max_corr_m`` metres."""
        init = np.asarray(init_T_target_source, np.float64)
        if len(target) < 3 or len(source) < 3:
            return RegResult(init.copy(), 0.0, False)
        if self.backend == "small_gicp":
            import small_gicp

            (tc, tt), (sc, _) = target.handle, source.handle
            r = small_gicp.align(tc, sc, tt, init, registration_type="GICP", max_correspondence_distance=max_corr_m,
                                 num_threads=self.threads, max_iterations=self.max_iterations)
            return RegResult(np.asarray(r.T_target_source, np.float64).copy(), r.num_inliers / max(len(source), 1),
                             bool(r.converged))
        import open3d as o3d

        reg = o3d.pipelines.registration
        with open3d_threads(self.threads):
            r = reg.registration_icp(source.handle, target.handle, max_corr_m, init,
                                     reg.TransformationEstimationPointToPlane(),
                                     reg.ICPConvergenceCriteria(max_iteration=self.max_iterations))
        return RegResult(np.asarray(r.transformation, np.float64).copy(), float(r.fitness), True)

    @staticmethod
    def information(target: Cloud, source: Cloud, T_target_source: np.ndarray, max_corr_m: float) -> np.ndarray:
        """(6, 6) float64 information matrix of an edge (Open3D's, from the correspondences within ``max_corr_m``):
        within :data:`HASH_MAX_CORR_M` from :func:`.information.information_matrix` (the same bytes), else Open3D's
        call (its KD-tree is the faster search for the tracking's wider 0.5 m)."""
        if max_corr_m <= HASH_MAX_CORR_M:
            from .information import information_matrix

            return information_matrix(target.points.astype(np.float64), source.points.astype(np.float64),
                                      np.asarray(T_target_source, np.float64), float(max_corr_m))
        import open3d as o3d

        with open3d_threads(1):
            return np.asarray(o3d.pipelines.registration.get_information_matrix_from_point_clouds(
                source.o3d(), target.o3d(), max_corr_m, np.asarray(T_target_source, np.float64)))


@contextlib.contextmanager
def open3d_threads(n: int):
    """Run Open3D's parallel loops on ``n`` threads for the block (1: sums in a fixed order, the same bytes
    every run); its console output is silenced to errors."""
    import open3d as o3d

    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(n)
    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            yield
    finally:
        o3d.utility.set_max_threads(before)


def register_points(target: np.ndarray, source: np.ndarray, init: np.ndarray | None = None, voxel_m: float = 0.1,
                    max_corr_m: float = 0.5, rounds: int = 3) -> tuple[np.ndarray, float]:
    """The rigid transform (4, 4) float64 taking ``source`` points (n, 3) onto ``target`` points (m, 3) (both
    metres, e.g. two maps' occupied voxel centres, ``merge --align``), from ``init`` (identity), by GICP in
    ``rounds`` passes with the correspondence distance halved each pass; and its fitness (inlier share).
    Deterministic (one thread)."""
    reg = Registration(voxel_m=voxel_m, max_iterations=60)
    t, s = reg.prepare(target), reg.prepare(source)
    T = np.eye(4) if init is None else np.asarray(init, np.float64)
    fit = 0.0
    for k in range(rounds):
        r = reg.align(t, s, T, max_corr_m / 2 ** k)
        T, fit = r.T_target_source, r.fitness
    return T, fit
