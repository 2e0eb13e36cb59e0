"""Pins every convention of CONVENTIONS.md: ERP angles and rays, projection round trips, the lattice."""

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry import erp, lattice
from panovocc_cli.geometry.poses import check_rigid, clearly_rigid, look_at, quat_to_rot, rot_to_quat


def test_erp_angles_follow_conventions():
    W, H = 8, 4
    theta, phi = erp.pixel_to_angles(np.arange(W), np.zeros(W), W, H)
    assert theta[0] == pytest.approx(0.5 * 2 * np.pi / W - np.pi)
    assert phi[0] == pytest.approx(np.pi / 2 - 0.5 * np.pi / H)
    rays = erp.ray_directions(W, H)
    assert rays.shape == (H, W, 3)
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1.0)
    # the centre column boundary (u = W/2 - 0.5, continuous) looks along +z
    assert np.allclose(erp.angles_to_ray(0.0, 0.0), [0, 0, 1])
    # moving right turns toward +x; row 0 looks up (-y in OpenCV)
    assert rays[H // 2, W // 2 + 1, 0] > 0 and rays[0, 0, 1] < 0 and rays[-1, 0, 1] > 0
    # column 0's left edge looks straight back (theta = -pi)
    assert np.allclose(erp.angles_to_ray(-np.pi, 0.0), [0, 0, -1], atol=1e-12)


def test_project_inverts_ray_directions():
    W, H = 64, 32
    rays = erp.ray_directions(W, H)
    u, v, r = erp.project(rays * 2.5, W, H)
    vv, uu = np.mgrid[0:H, 0:W]
    assert np.allclose(u, uu, atol=1e-9) and np.allclose(v, vv, atol=1e-9) and np.allclose(r, 2.5)
    row, col, _ = erp.project_to_pixel(rays * 3.0, W, H)
    assert np.array_equal(row, vv) and np.array_equal(col, uu)


def test_box_room_depth_closed_form():
    """A camera at the centre of a 2a x 2b x 2c box: radial depth is min over faces of half-size / |ray_axis|."""
    W, H = 128, 64
    half = np.array([2.0, 1.5, 1.25])
    rays = erp.ray_directions(W, H)
    with np.errstate(divide="ignore"):
        t = np.min(half / np.abs(rays), axis=-1)
    pts = erp.backproject(t, rays)
    # every point lies on the box boundary
    assert np.allclose(np.max(np.abs(pts) / half, axis=-1), 1.0)
    # straight ahead (+z) the depth is the z half-size
    ahead = erp.angles_to_ray(0.0, 0.0)
    assert np.isclose(np.min(half[ahead != 0] / np.abs(ahead[ahead != 0])), half[2])


def test_local_frames_orthonormal_and_aligned():
    th, ph = np.array([0.3, -2.0]), np.array([0.1, 1.2])
    E = erp.local_frames(th, ph)
    for e in E:
        assert np.allclose(e.T @ e, np.eye(3), atol=1e-12)
    assert np.allclose(E[..., 2], erp.angles_to_ray(th, ph))
    d = 1e-6
    dth = (erp.angles_to_ray(th + d, ph) - erp.angles_to_ray(th, ph)) / d
    assert np.allclose(dth / np.linalg.norm(dth, axis=-1, keepdims=True), E[..., 0], atol=1e-5)


def test_erp_size_checks():
    with pytest.raises(PanovoccError):
        erp.check_erp_size(1023)
    with pytest.raises(PanovoccError):
        erp.check_erp_size(1024, 500)
    assert erp.check_erp_size(1024) == (1024, 512)



def test_compiled_projection_is_project_to_pixel():
    """erp.cam_pixel (the free-space test's projection, polynomial atan2) gives project_to_pixel's pixel and
    range, but where a point lies within the polynomial's error (1e-5 rad) of a pixel border."""
    H, W = 256, 512
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(20000, 3)) * rng.uniform(0.2, 9.0, size=(20000, 1))
    pts[:4] = [[0, 0, 1], [0, 0, -1], [0, -2, 0], [0, 3, 0]]  # ahead, straight back, zenith, nadir
    row, col, r = erp.project_to_pixel(pts, W, H)
    got = np.array([erp.cam_pixel(x, y, z, H, W) for x, y, z in pts])
    np.testing.assert_allclose(got[:, 0], r, rtol=1e-12)
    u, v, _ = erp.project(pts, W, H)
    border = 1e-5 * np.array([W, H]) / (2 * np.pi)  # the polynomial's error, in pixels
    near = (np.abs((u + 0.5) - np.round(u + 0.5)) < border[0]) | (np.abs((v + 0.5) - np.round(v + 0.5)) < border[1])
    same = (got[:, 1] == row) & (got[:, 2] == col)
    assert same[~near].all() and (~near).sum() > 19000

def test_lattice_index_center_and_keys():
    h = 0.08
    pts = np.array([[0.0, 0.0, 0.0], [0.079999, -0.0001, 1.0], [-3.2, 5.1, 2.4]])
    idx = lattice.point_to_index(pts, h)
    assert idx.tolist()[0] == [0, 0, 0] and idx.tolist()[1][:2] == [0, -1]
    c = lattice.index_to_center(idx, h)
    assert np.all(np.abs(c - pts) <= h / 2 + 1e-9)
    rng = np.random.default_rng(0)
    many = rng.integers(-100000, 100000, size=(1000, 3))
    assert np.array_equal(lattice.unpack_keys(lattice.pack_keys(many)), many)
    o = lattice.index_to_center([3, -2, 7], h)
    assert lattice.origin_to_index(o, h).tolist() == [3, -2, 7]
    with pytest.raises(PanovoccError):
        lattice.origin_to_index([0.0, 0.0, 0.0], h)  # a corner, not a centre



def test_one_key_layout_for_numpy_and_the_kernels():
    """The kernels compile lattice.pack_index / unpack_index themselves: their keys are pack_keys', in
    x-major order, to the edges of the range; the memory's block keys are the keys of index // 8."""
    import numba as nb

    from panovocc_cli.mapping import memory

    r = lattice.KEY_RANGE - 1
    idx = np.array([[0, 0, 0], [-1, 0, 0], [0, -1, 5], [r, -r, r], [-r, r, -r], [r, r, r], [-r, -r, -r],
                    [123456, -654321, 7]], np.int64)
    keys = lattice.pack_keys(idx)
    pack, unpack = nb.njit(lattice.pack_index), nb.njit(lattice.unpack_index)
    for (i, j, k), key in zip(idx, keys):
        assert pack(i, j, k) == key and unpack(key) == (i, j, k)
        assert memory._pack(i, j, k) == key and memory._unpack(key) == (i, j, k)  # as the kernels compile it
        assert lattice.pack_index(int(i), int(j), int(k)) == key  # plain Python ints too
    order = np.lexsort(idx.T[::-1])  # x-major, then y, then z
    assert np.array_equal(np.argsort(keys), order)
    for key, (i, j, k) in zip(keys, idx):
        bkey, o = memory._block_key_and_offset(key)
        assert bkey == lattice.pack_keys(np.array([[i // 8, j // 8, k // 8]]))[0]
        assert o == (i % 8) * 64 + (j % 8) * 8 + k % 8 and memory._voxel_key(bkey, o) == key
    with pytest.raises(PanovoccError, match="range"):
        lattice.pack_keys(np.array([[lattice.KEY_RANGE, 0, 0]]))

def test_poses_and_quaternions():
    T = look_at([1.0, 2.0, 1.5], [1.0, 0.0, 0.0])
    check_rigid(T)
    assert np.allclose(T[:3, 2], [1, 0, 0]) and np.allclose(T[:3, 1], [0, 0, -1])  # y down = -Z world
    R = T[:3, :3]
    assert np.allclose(quat_to_rot(rot_to_quat(R)), R)
    bad = T.copy()
    bad[:3, :3] *= 1.1
    with pytest.raises(PanovoccError, match="not rigid"):
        check_rigid(bad)


def test_clearly_rigid_marks_only_poses_check_rigid_accepts():
    """The batched test beside check_rigid: rigid poses True; a scale, a reflection, a NaN, a bad last row False
    (check_rigid refuses each); a pose within the tolerance but off by more than a tenth of it False too (it is
    then checked one by one, and check_rigid accepts it)."""
    from panovocc_cli.config import RIGID_TOL

    rng = np.random.default_rng(5)
    T = np.tile(np.eye(4), (7, 1, 1))
    for i in range(7):
        T[i, :3, :3] = quat_to_rot(rng.standard_normal(4))
        T[i, :3, 3] = rng.uniform(-10, 10, 3)
    T[1, :3, :3] *= 1.1
    T[2, :3, 0] *= -1
    T[3, 0, 1] = np.nan
    T[4, 3, 0] = 0.5
    T[5, :3, :3] *= 1 + 0.4 * RIGID_TOL
    assert clearly_rigid(T).tolist() == [True, False, False, False, False, False, True]
    for i in (1, 2, 3, 4):
        with pytest.raises(PanovoccError):
            check_rigid(T[i])
    check_rigid(T[5])
