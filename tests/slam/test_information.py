"""slam/information.py: an edge's information matrix from a hash of the target's points, equal to Open3D's
``get_information_matrix_from_point_clouds`` bit for bit (the final refinement's and the loops' edges use it)."""

import numpy as np
import pytest

from panovocc_cli.geometry.drift import so3_exp
from panovocc_cli.slam.information import information_matrix
from panovocc_cli.slam.registration import HASH_MAX_CORR_M, Cloud, Registration, open3d_threads


def _open3d(target, source, T, max_corr):
    import open3d as o3d

    pc = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(p, np.float64))) for p in (source, target)]
    with open3d_threads(1):
        return np.asarray(o3d.pipelines.registration.get_information_matrix_from_point_clouds(pc[0], pc[1], max_corr, T))


def _room(rng, n, offset=(0.0, 0.0, 0.0)):
    """n points on the walls, floor and ceiling of a 6 x 4 x 2.6 m room, with 5 mm of noise, as float32 (a cloud's)."""
    p = rng.uniform([-3.0, -2.0, -1.3], [3.0, 2.0, 1.3], size=(n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1, 1) * np.array([3.0, 2.0, 1.3])[axis]
    return (p + rng.normal(0.0, 0.005, p.shape) + offset).astype(np.float32)


@pytest.mark.parametrize("seed", range(6))
def test_equals_open3d_bit_for_bit(seed):
    """Registered and misregistered pairs, correspondence distances from 2 cm to 0.2 m, clouds of 10 to 8,000 points,
    sources partly out of reach and a room far from the origin: the same 36 float64 as Open3D's, every time."""
    rng = np.random.default_rng(seed)
    target = _room(rng, int(rng.integers(10, 8000)), offset=(0.0, 0.0, 0.0) if seed % 2 else (2000.0, -900.0, 12.0))
    T = np.eye(4)
    T[:3, :3] = so3_exp(rng.normal(0.0, 0.05, 3))
    T[:3, 3] = rng.normal(0.0, 0.3, 3)
    source = ((target.astype(np.float64) - T[:3, 3]) @ T[:3, :3]).astype(np.float32)  # T maps source onto target
    source = np.concatenate([source, _room(rng, 500, offset=(9.0, 0.0, 0.0))])  # a room the target does not hold
    for max_corr in (0.02, 0.05, 0.1, 0.2):
        for Tuse in (T, T @ np.array([[1, 0, 0, 0.03], [0, 1, 0, -0.02], [0, 0, 1, 0.01], [0, 0, 0, 1.0]])):
            got = information_matrix(target.astype(np.float64), source.astype(np.float64), Tuse, max_corr)
            want = _open3d(target, source, Tuse, max_corr)
            assert np.array_equal(got, want), (max_corr, np.abs(got - want).max())
    assert 0 < want[5, 5] < len(source)  # some correspondences, not all: the case tests something


def test_registration_information_either_way_and_edge_cases():
    """``Registration.information`` takes the hash within HASH_MAX_CORR_M and Open3D's call beyond it: Open3D's matrix
    both ways; empty clouds give zeros; a target point beyond the hash's cells is refused, not wrapped."""
    rng = np.random.default_rng(9)
    a, b = Cloud(_room(rng, 3000)), Cloud(_room(rng, 3000))
    T = np.eye(4)
    T[:3, 3] = [0.01, -0.02, 0.0]
    for max_corr in (0.1, HASH_MAX_CORR_M, 0.5):
        assert np.array_equal(Registration.information(a, b, T, max_corr), _open3d(a.points, b.points, T, max_corr))
    empty = np.zeros((0, 3))
    assert not information_matrix(empty, b.points.astype(np.float64), T, 0.1).any()
    assert not information_matrix(a.points.astype(np.float64), empty, T, 0.1).any()
    with pytest.raises(ValueError, match="too far"):
        information_matrix(np.array([[1e5, 0.0, 0.0]]), np.zeros((1, 3)), np.eye(4), 0.1)
