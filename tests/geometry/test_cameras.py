"""Camera layer: pinhole round trips in closed form, the view rig's rotations, radial <-> z-depth."""

import math

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.cameras import ErpCamera, PinholeCamera, ViewRig, view_rotation
from panovocc_cli.geometry.pinhole import nb_pixel_ray, nb_project

CAM = PinholeCamera(fx=300.0, fy=280.0, cx=159.5, cy=101.25, width=320, height=200)


def test_from_fov_closed_form():
    cam = PinholeCamera.from_fov(64, 48, math.pi / 2)
    assert cam.fx == cam.fy == pytest.approx(32.0)  # 64 / (2 tan 45 deg)
    assert (cam.cx, cam.cy) == (31.5, 23.5)
    # the outer pixel edges (-0.5 and W - 0.5) look 45 degrees left and right
    r = cam.pixel_rays(np.array([-0.5, 63.5]), np.array([23.5, 23.5]))
    assert np.degrees(np.arctan2(r[:, 0], r[:, 2])) == pytest.approx([-45.0, 45.0])
    np.testing.assert_allclose(cam.K, [[32, 0, 31.5], [0, 32, 23.5], [0, 0, 1]])


def test_pixel_ray_pixel_round_trip():
    rays = CAM.rays()
    assert rays.shape == (200, 320, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    depth = np.random.default_rng(0).uniform(0.3, 9.0, (200, 320))
    u, v, z = CAM.project(rays * depth[..., None])
    vv, uu = np.mgrid[0:200, 0:320]
    np.testing.assert_allclose(u, uu, atol=1e-9)
    np.testing.assert_allclose(v, vv, atol=1e-9)
    np.testing.assert_allclose(z, depth * rays[..., 2], rtol=1e-12)
    # the centre ray is the optical axis; a known off-axis pixel in closed form
    np.testing.assert_allclose(CAM.pixel_rays(159.5, 101.25), [0, 0, 1])
    d = np.array([(459.5 - 159.5) / 300.0, 0.0, 1.0])  # one focal length right: 45 degrees
    np.testing.assert_allclose(CAM.pixel_rays(459.5, 101.25), d / np.linalg.norm(d))
    assert np.isnan(CAM.project(np.array([0.1, 0.2, -1.0]))[0])  # behind the camera


def test_radial_z_round_trip_closed_form():
    z = np.random.default_rng(1).uniform(0.1, 20.0, (200, 320))
    z[5, 7] = 0.0
    r = CAM.z_to_radial(z)
    np.testing.assert_allclose(CAM.radial_to_z(r), z, rtol=1e-12)
    assert r[5, 7] == 0.0
    # radial = |backprojected point|; z = its third coordinate
    p = CAM.backproject(z)
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), r, rtol=1e-12)
    np.testing.assert_allclose(p[..., 2], z)
    # corner pixel (0, 0): r / z = |((0 - cx)/fx, (0 - cy)/fy, 1)|
    assert r[0, 0] / z[0, 0] == pytest.approx(math.hypot(159.5 / 300.0, 101.25 / 280.0, 1.0))


def test_numba_helpers_match_numpy():
    from numba import njit

    @njit
    def go(u, v):
        x, y, z = nb_pixel_ray(u, v, 300.0, 280.0, 159.5, 101.25)
        pu, pv = nb_project(2.5 * x, 2.5 * y, 2.5 * z, 300.0, 280.0, 159.5, 101.25)
        return x, y, z, pu, pv

    x, y, z, pu, pv = go(17.25, 190.0)
    np.testing.assert_allclose([x, y, z], CAM.pixel_rays(17.25, 190.0), atol=1e-15)
    assert (pu, pv) == pytest.approx((17.25, 190.0))


def test_pinhole_rejects_bad_values():
    with pytest.raises(PanovoccError):
        PinholeCamera(0.0, 1.0, 0.0, 0.0, 10, 10)
    with pytest.raises(PanovoccError):
        PinholeCamera(1.0, 1.0, float("nan"), 0.0, 10, 10)
    with pytest.raises(PanovoccError):
        PinholeCamera.from_fov(10, 10, math.pi)
    with pytest.raises(PanovoccError):
        PinholeCamera(1.0, 1.0, 0.0, 0.0, 0, 10)


def test_view_rotation_axes():
    # forward view: identity; right view (az 90) looks along +x; up view (pitch +90) along -y
    np.testing.assert_allclose(view_rotation(0.0, 0.0), np.eye(3), atol=1e-15)
    np.testing.assert_allclose(view_rotation(math.pi / 2, 0.0)[:, 2], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(view_rotation(0.0, math.pi / 2)[:, 2], [0, -1, 0], atol=1e-15)
    for a in np.linspace(-3, 3, 7):
        for p in np.linspace(-1.5, 1.5, 5):
            R = view_rotation(a, p)
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
            assert np.linalg.det(R) == pytest.approx(1.0)
            assert abs(R[1, 0]) < 1e-15  # no roll: the view's x axis is horizontal
            # the optical axis is the panorama's ray of longitude a, latitude p (CONVENTIONS.md)
            np.testing.assert_allclose(R[:, 2], [math.cos(p) * math.sin(a), -math.sin(p), math.cos(p) * math.cos(a)],
                                       atol=1e-15)


def test_twelve_rig_layout_and_poses():
    rig = ViewRig.twelve(32)
    assert len(rig) == 12 and len(set(rig.names)) == 12
    assert rig.names[0] == "view_00_az000_up" and rig.names[5] == "view_05_az090_mid"
    assert rig.names[11] == "view_11_az270_down"
    assert [round(math.degrees(v.pitch_rad)) for v in rig] == [45] * 4 + [0] * 4 + [-45] * 4
    assert [round(math.degrees(v.azimuth_rad)) for v in rig] == [0, 90, 180, 270] * 3
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = view_rotation(0.7, 0.2)
    T_world_cam[:3, 3] = [1.0, -2.0, 0.5]
    for v in rig:
        T = v.T_world_view(T_world_cam)
        np.testing.assert_allclose(T[:3, 3], T_world_cam[:3, 3])  # the views share the panorama's centre
        np.testing.assert_allclose(T, T_world_cam @ v.T_cam_view)
        # a point on the view's optical axis projects to the view's principal point
        p_world = T[:3, :3] @ [0, 0, 3.0] + T[:3, 3]
        p_view = np.linalg.inv(T) @ np.append(p_world, 1.0)
        u, vv, z = v.camera.project(p_view[:3])
        assert (u, vv, z) == pytest.approx((15.5, 15.5, 3.0))


def test_cube_rig_covers_the_sphere_once():
    rig = ViewRig.cube(8)
    dirs = np.array([v.R_cam_view[:, 2] for v in rig])
    axes = sorted(tuple(int(c) for c in np.round(d)) for d in dirs)  # +-x, +-y, +-z once each
    assert axes == sorted([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])
    np.testing.assert_allclose(dirs, np.round(dirs), atol=1e-12)
    # every ERP ray lands in exactly one face's frustum (ties on cube edges excluded)
    rays = ErpCamera(64, 32).rays().reshape(-1, 3)
    hits = np.zeros(len(rays), int)
    for v in rig:
        u, vv, z = v.camera.project(rays @ v.R_cam_view)
        hits += (z > 0) & (u > -0.5) & (u < 7.5) & (vv > -0.5) & (vv < 7.5)
    assert (hits >= 1).all() and (hits == 1).mean() > 0.9


def test_erp_camera_project_inverts_rays():
    cam = ErpCamera(64, 32)
    u, v, r = cam.project(cam.rays() * 2.0)
    vv, uu = np.mgrid[0:32, 0:64]
    np.testing.assert_allclose(u, uu, atol=1e-9)
    np.testing.assert_allclose(v, vv, atol=1e-9)
    np.testing.assert_allclose(r, 2.0)


def test_cube_faces_are_the_pyrender_backends_exact_axes():
    """The pyrender backend takes its faces from ViewRig.cube: the same rotations it had written out."""
    faces = np.stack([v.R_cam_view for v in ViewRig.cube(4)])
    written = np.array([
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],  # front +z
        [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],  # right +x
        [[-1, 0, 0], [0, 1, 0], [0, 0, -1]],  # back -z
        [[0, 0, -1], [0, 1, 0], [1, 0, 0]],  # left -x
        [[1, 0, 0], [0, 0, -1], [0, 1, 0]],  # up -y
        [[1, 0, 0], [0, 0, 1], [0, -1, 0]],  # down +y
    ], dtype=np.float64)
    assert faces.tobytes() == written.tobytes()
