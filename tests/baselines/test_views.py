"""The twelve-view split: RGB against py360convert's e2p, z-depth lifted back onto a closed-form box room,
labels by nearest neighbour, and ``panovocc views`` end to end (layout, poses, bytes, overwrite rule)."""

import json
import math
import os

import numpy as np
import pytest
from box_room import HI, LO, box_depth, turned_pose

from panovocc_cli.baselines.views import ViewSampler
from panovocc_cli.geometry.cameras import ErpCamera, ViewRig

W = 256


def smooth_texture(W):
    """(W/2, W, 3) uint8, smooth and asymmetric under left-right and up-down mirroring."""
    v, u = np.mgrid[0:W // 2, 0:W].astype(float)
    th, ph = 2 * np.pi * u / W, np.pi * v / (W // 2)
    img = np.stack([127 + 100 * np.sin(3 * th + 0.4) * np.cos(2 * ph), 127 + 100 * np.cos(2 * th + 1.0),
                    127 + 90 * np.sin(5 * ph + th)], -1)
    return np.clip(img, 0, 255).astype(np.uint8)


def box_face_labels(W, T):
    """(W/2, W) int64: 1..6, the box wall each ERP pixel's ray hits (closed form)."""
    d = ErpCamera(W, W // 2).rays() @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (HI - o) / d, (LO - o) / d)
    t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
    axis = t.argmin(-1)
    sign = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
    return 1 + 2 * axis + sign


def test_rgb_matches_py360convert_e2p():
    """Every view equals py360convert's e2p of the same panorama, within one grey level (cv2.remap's 1/32-pixel
    fixed point there, float64 here). Mapping of conventions: e2p(u_deg = azimuth, v_deg = pitch), both
    turning right / up; e2p puts its first and last pixel centres (not edges) at +-fov/2, so it is given
    fov' = 2 atan(tan(fov/2) (S - 1) / S) to sample the same rays."""
    py360convert = pytest.importorskip("py360convert")
    img = smooth_texture(W)
    S, fov = 40, math.radians(90.0)
    rig = ViewRig.twelve(S, fov)
    rgb, _, _ = ViewSampler(rig, W).split(img, np.ones((W // 2, W)), None)
    fov_e2p = 2 * math.degrees(math.atan(math.tan(fov / 2) * (S - 1) / S))
    for k, view in enumerate(rig):
        az, pitch = math.degrees(view.azimuth_rad), math.degrees(view.pitch_rad)
        ref = py360convert.e2p(img, fov_e2p, az, pitch, (S, S), mode="bilinear")
        diff = np.abs(ref.astype(int) - rgb[k].astype(int))
        assert diff.max() <= 1 and diff.mean() < 0.2, view.name
        if az % 180 or pitch:  # the mirrored direction is a different picture: the test can tell
            wrong = py360convert.e2p(img, fov_e2p, -az, -pitch, (S, S), mode="bilinear")
            assert np.abs(wrong.astype(int) - rgb[k].astype(int)).mean() > 10, view.name


@pytest.mark.parametrize("pitch_deg", [45.0, 60.0])
def test_depth_lifted_lands_on_the_box(pitch_deg):
    """z-depth of each view x its pixel rays, moved by T_world_view, lies on a wall of the box room."""
    W = 512
    T = turned_pose(0.4, (0.3, -0.2, 0.1))
    depth = box_depth(W, T)
    rig = ViewRig.twelve(64, math.radians(90.0), math.radians(pitch_deg))
    _, z, _ = ViewSampler(rig, W).split(None, depth, None)
    errs = []
    for k, view in enumerate(rig):
        assert (z[k] > 0).all()
        p_view = view.camera.backproject(z[k]).reshape(-1, 3)
        Tv = view.T_world_view(T)
        p = p_view @ Tv[:3, :3].T + Tv[:3, 3]
        dist = np.minimum(np.abs(p - LO), np.abs(p - HI)).min(-1)  # distance to the nearest wall plane
        assert (p > LO - 0.05).all() and (p < HI + 0.05).all()
        errs.append(dist)
        # the exact z-depth of the box along the view pixels' rays, for comparison
        d = view.camera.rays().reshape(-1, 3) @ Tv[:3, :3].T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (HI - Tv[:3, 3]) / d, (LO - Tv[:3, 3]) / d)
        r_exact = np.where(np.isfinite(t) & (t > 0), t, np.inf).min(-1)
        z_exact = view.camera.radial_to_z(r_exact.reshape(64, 64))
        rel = np.abs(z[k] - z_exact) / z_exact
        # nearest ERP pixel: its ray is up to half a pixel (delta / 2, delta = 2 pi / W) off the view pixel's,
        # which changes the depth by about that angle x tan(incidence)
        delta = 2 * np.pi / W
        assert np.median(rel) < delta / 2 and rel.max() < 4 * delta, view.name
    errs = np.concatenate(errs)
    assert np.median(errs) < 5e-3 and np.percentile(errs, 99) < 0.03  # metres, walls 1.1 to 3.5 m away


def test_labels_nearest_neighbour():
    W = 256
    T = turned_pose(0.9, (0.4, 0.3, -0.2))
    src = box_face_labels(W, T) * 7  # ids 7, 14, ..., 42: a blend would make others
    rig = ViewRig.twelve(48)
    _, _, lab = ViewSampler(rig, W).split(None, np.ones((W // 2, W)), src)
    assert lab.dtype == np.int64 and lab.shape == (12, 48, 48)
    assert set(np.unique(lab)) <= set(np.unique(src))
    # each view pixel carries the wall its own ray hits, except within about a pixel of a box edge
    for k, view in enumerate(rig):
        Tv = view.T_world_view(T)
        d = view.camera.rays() @ Tv[:3, :3].T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (HI - Tv[:3, 3]) / d, (LO - Tv[:3, 3]) / d)
        axis = np.where(np.isfinite(t) & (t > 0), t, np.inf).argmin(-1)
        sign = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
        truth = 7 * (1 + 2 * axis + sign)
        assert (lab[k] == truth).mean() > 0.95, view.name


def write_box_sequence(root, frames=3, W=128):
    from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses

    poses = np.stack([turned_pose(0.3 * i, (0.2 * i, -0.1, 0.05 * i)) for i in range(frames)])
    root.mkdir(parents=True)
    write_meta(root, SequenceMeta(width=W, height=W // 2, frames=frames,
                                  class_names=["unlabeled", "a", "b", "c", "d", "e", "f"]))
    write_sequence_poses(root, poses)
    for d in ("rgb", "depth", "semantic"):
        (root / d).mkdir()
    for i, T in enumerate(poses):
        write_frame(root, i, np.roll(smooth_texture(W), 5 * i, axis=1), box_depth(W, T), box_face_labels(W, T) % 7)
    return poses


def tree_bytes(root):
    out = {}
    for dirpath, _, files in os.walk(root):
        for f in files:
            p = os.path.join(dirpath, f)
            out[os.path.relpath(p, root)] = open(p, "rb").read()
    return out


@pytest.mark.slow
def test_views_cli_end_to_end(tmp_path, capsys):
    from panovocc_cli.cli import main
    from panovocc_cli.io.sequence import Sequence

    def cli(*argv):
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in argv])
        return int(e.value.code or 0), capsys.readouterr()

    poses = write_box_sequence(tmp_path / "seq")
    out = tmp_path / "views"
    rc, cap = cli("views", tmp_path / "seq", out, "--size", 24, "--fov-deg", 90)
    assert rc == 0, cap.err
    doc = json.loads((out / "views.json").read_text())
    names = [v["name"] for v in doc["views"]]
    assert names == ViewRig.twelve(24).names
    assert sorted(p.name for p in out.iterdir()) == sorted(names + ["views.json", "config.json"])
    rig = ViewRig.twelve(24)
    for view in rig:
        s = Sequence(out / view.name)
        assert s.meta.camera == "pinhole" and s.meta.shape == (24, 24) and len(s) == 3
        assert (s.meta.fx, s.meta.fy, s.meta.cx, s.meta.cy) == pytest.approx((12.0, 12.0, 11.5, 11.5))
        assert s.meta.class_names == ["unlabeled", "a", "b", "c", "d", "e", "f"]
        np.testing.assert_allclose(s.poses, poses @ view.T_cam_view, atol=1e-9)
        for i in range(3):
            z = s.depth(i)  # millimetre z-depth: lifted, on a wall within the ERP's nearest-pixel error + 1 mm
            p = view.camera.backproject(z).reshape(-1, 3) @ s.poses[i][:3, :3].T + s.poses[i][:3, 3]
            assert np.median(np.minimum(np.abs(p - LO), np.abs(p - HI)).min(-1)) < 0.03  # 128 px ERP: 2.8 deg pixels
            assert set(np.unique(s.labels(i))) <= set(range(7))
            assert s.rgb(i).shape == (24, 24, 3)
    # same inputs, same bytes (views.json differs only by the output path it records)
    rc, cap = cli("views", tmp_path / "seq", tmp_path / "views2", "--size", 24)
    assert rc == 0
    a, b = tree_bytes(out), tree_bytes(tmp_path / "views2")
    assert a.keys() == b.keys() and len(a) == 2 + 12 * (1 + 1 + 3 * 3)
    assert all(a[k] == b[k] for k in a if k not in ("views.json", "config.json"))
    doc2 = json.loads(b["views.json"])
    assert doc2["config"].pop("out") != doc["config"].pop("out") and doc2 == doc
    c1, c2 = json.loads(a["config.json"]), json.loads(b["config.json"])
    assert c1.pop("out") != c2.pop("out") and c1 == c2 and c1["fov_deg"] == 90.0 and c1["pitch_deg"] == 45.0
    # the overwrite rule: refused without --overwrite, replaced with it, never over another kind of folder
    rc, cap = cli("views", tmp_path / "seq", out, "--size", 24)
    assert rc == 2 and "--overwrite" in cap.err
    rc, cap = cli("views", tmp_path / "seq", out, "--size", 16, "--overwrite")
    assert rc == 0 and Sequence(out / names[0]).meta.width == 16
    rc, cap = cli("views", tmp_path / "seq", tmp_path / "seq", "--overwrite")
    assert rc == 2 and "input" in cap.err
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    rc, cap = cli("views", tmp_path / "seq", tmp_path / "other", "--overwrite")
    assert rc == 2 and (tmp_path / "other" / "keep.txt").read_text() == "x"
    rc, cap = cli("views", tmp_path / "seq", tmp_path / "bad", "--fov-deg", 180)
    assert rc == 2 and "--fov-deg" in cap.err and not (tmp_path / "bad").exists()


def test_views_bad_inputs_write_nothing(tmp_path, capsys):
    from panovocc_cli.cli import main

    def cli(*argv):
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in argv])
        return int(e.value.code or 0), capsys.readouterr().err

    seq = tmp_path / "seq"
    write_box_sequence(seq, frames=2, W=64)
    out = tmp_path / "out"
    rc, err = cli("views", tmp_path / "nope", out)
    assert rc == 2 and "nope" in err and err.count("\n") == 1
    rc, err = cli("views", seq, out, "--size", 4)
    assert rc == 2 and "--size" in err
    rc, err = cli("views", seq, out, "--pitch-deg", -10)
    assert rc == 2 and "--pitch-deg" in err
    (seq / "depth" / "000001.png").unlink()
    rc, err = cli("views", seq, out)
    assert rc == 2 and "000001" in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    # a pinhole sequence (a view of a previous run) is not a panorama
    seq2 = tmp_path / "seq2"
    write_box_sequence(seq2, frames=1, W=64)
    assert cli("views", seq2, out, "--size", 8)[0] == 0
    rc, err = cli("views", out / "view_00_az000_up", tmp_path / "out2")
    assert rc == 2 and "erp" in err and not (tmp_path / "out2").exists()


def test_views_help_names_units_and_options_are_the_config():
    import typer

    from panovocc_cli.cli import load_commands
    from panovocc_cli.cli.options import option_specs
    from panovocc_cli.baselines.views import ViewsConfig

    cmd = typer.main.get_command(load_commands()).commands["views"]
    helps = {p.name: p.help or "" for p in cmd.params}
    assert {s.name for s in option_specs(ViewsConfig)} == set(helps) - {"help"}
    assert "degrees" in helps["fov_deg"] and "pixels" in helps["size"] and "10 <= x <= 170" in helps["fov_deg"]
