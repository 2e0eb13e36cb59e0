"""``panovocc baselines run``: the Open3D TSDF stream on the global lattice (closed form), persp-tsdf's merge of
its streams, forward-only's single view, single-pano's local boxes and per-frame scores, and the output rules."""

import json
import math

import numpy as np
import pytest
from semantics_helpers import BOXES, CLASS_NAMES, ROOM_HI, ROOM_LO

from panovocc_cli.baselines.single_pano import local_box
from panovocc_cli.baselines.tsdf import TsdfStream
from panovocc_cli.evaluation.align import resample_onto
from panovocc_cli.evaluation.metrics import evaluate
from panovocc_cli.geometry.cameras import PinholeCamera
from panovocc_cli.geometry.lattice import index_to_center
from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import read_grid

H = 0.08


def occupied_centres(g: Grid) -> np.ndarray:
    return g.centers(np.argwhere((g.labels != 0) & (g.labels != 255)))


def surface_distance(p: np.ndarray) -> np.ndarray:
    """Distance (n,) metres from points (n, 3) inside the room to its nearest surface: walls, floor, ceiling, boxes."""
    d = np.minimum(p - ROOM_LO, ROOM_HI - p).min(axis=1)
    for _, lo, hi in BOXES:
        lo, hi = np.asarray(lo), np.asarray(hi)
        outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0), axis=1)
        inside = np.minimum(p - lo, hi - p).min(axis=1)
        d = np.minimum(d, np.where(outside > 0, outside, np.maximum(inside, 0)))
    return d


def test_tsdf_stream_plane_lands_in_its_voxel_layer():
    """A fronto-parallel plane at z = 2.03 m seen 3 times: the occupied voxels are exactly the layer
    [2.00, 2.08) (lattice voxel 25), free voxels lie in front of it, classes follow the pixels' votes."""
    cam = PinholeCamera.from_fov(48, 48, math.pi / 2)
    s = TsdfStream(cam, H, 2)
    z = np.full((48, 48), 2.03, np.float32)
    cls = np.zeros((48, 48), np.int64)
    cls[:, 24:] = 1
    for _ in range(3):
        s.integrate(z, np.eye(4), None, cls)
    g = s.grid(["wall", "door"])
    occ = occupied_centres(g)
    assert len(occ) > 100 and np.allclose(occ[:, 2], 25.5 * H)
    lab = g.labels[(g.labels != 0) & (g.labels != 255)]
    c = g.centers(np.argwhere((g.labels != 0) & (g.labels != 255)))
    assert np.all(lab[c[:, 0] < -0.1] == 1) and np.all(lab[c[:, 0] > 0.1] == 2)  # wall left, door right
    free = g.centers(np.argwhere(g.labels == 0))
    assert len(free) and free[:, 2].max() < 2.0
    assert np.all(np.abs(g.origin / H - 0.5 - np.round(g.origin / H - 0.5)) < 1e-9)  # on the global lattice


def test_pixel_classes_at_the_semantic_stride():
    """Logits at stride 2 (pixels (2i, 2j) of an 8x16 panorama): each pixel takes the nearest sampled pixel's class."""
    from panovocc_cli.baselines.persp_tsdf import pixel_classes
    from panovocc_cli.frame import Frame
    from panovocc_cli.geometry.cameras import ErpCamera

    cls = np.arange(32).reshape(4, 8) % 3
    logits = np.eye(3, dtype=np.float32)[cls]  # (4, 8, 3)
    f = Frame(np.zeros((8, 16, 3), np.uint8), np.ones((8, 16), np.float32), np.eye(4), ErpCamera(16, 8), logits)
    full = pixel_classes(f)
    assert full.shape == (8, 16)
    assert np.array_equal(full[::2, ::2], cls)  # the sampled pixels keep their own class
    assert np.array_equal(full[1::2, 1::2], cls)  # odd pixels: the sample above-left (a tie at distance 1)
    f.logits = np.eye(3, dtype=np.float32)[np.repeat(np.repeat(cls, 2, 0), 2, 1)]  # stride 1
    assert np.array_equal(pixel_classes(f), full)


def test_tsdf_stream_without_depth_is_empty():
    """A stream that never had a valid depth pixel (all 0, or all beyond the range) gives an all-unobserved grid."""
    s = TsdfStream(PinholeCamera.from_fov(16, 16, math.pi / 2), H, 2, max_range=5.0)
    assert set(np.unique(s.grid(["a", "b"]).labels)) == {255}
    s.integrate(np.zeros((16, 16)), np.eye(4), None, np.zeros((16, 16), np.int64))
    s.integrate(np.full((16, 16), 9.0), np.eye(4), None, np.zeros((16, 16), np.int64))
    g = s.grid(["a", "b"])
    assert g.labels.shape == (1, 1, 1) and set(np.unique(g.labels)) == {255} and s.frames == 2


def test_persp_tsdf_streams_merge_and_surfaces(room, tmp_path, cli):
    out = tmp_path / "p"
    code, so, err = cli(["baselines", "run", "persp-tsdf", room, out, "--noise", "0", "--quiet"])
    assert code == 0, err
    pred = read_grid(out / "prediction.npz")
    streams = sorted((out / "streams").glob("*.npz"))
    assert len(streams) == 12 and streams[0].name == "view_00_az000_up.npz"
    code, _, err = cli(["baselines", "merge", tmp_path / "m.npz", *streams])  # the paper's rule, from the files
    assert code == 0, err
    m = read_grid(tmp_path / "m.npz")
    assert np.array_equal(m.labels, pred.labels) and np.allclose(m.origin, pred.origin)
    assert m.class_names == pred.class_names
    p = occupied_centres(pred)
    assert len(p) > 1000 and np.quantile(surface_distance(p), 0.95) < 1.5 * H
    floor = (p[:, 2] < H) & (np.abs(p[:, 0]) < 0.5) & (np.abs(p[:, 1] - 0.3) < 0.4)  # open floor, off the rug
    lab = pred.labels[(pred.labels != 0) & (pred.labels != 255)][floor]
    assert floor.sum() > 5 and np.mean(np.array(pred.class_names)[lab] == "floor") > 0.9
    doc = json.loads((out / "baseline.json").read_text())
    assert doc["baseline"] == "persp-tsdf" and len(doc["views"]) == 12 and doc["segmenter"] == "simulated"
    assert json.loads((out / "config.json").read_text())["noise"] == 0
    before = (out / "prediction.npz").read_bytes()
    code, _, err = cli(["baselines", "run", "persp-tsdf", room, out, "--noise", "0", "--quiet", "--overwrite"])
    assert code == 0 and (out / "prediction.npz").read_bytes() == before  # deterministic


def test_forward_only_sees_only_ahead(room, tmp_path, cli):
    out = tmp_path / "f"
    code, _, err = cli(["baselines", "run", "forward-only", room, out, "--quiet", "--segmenter", "none"])
    assert code == 0, err
    pred = read_grid(out / "prediction.npz")
    p = occupied_centres(pred)
    from panovocc_cli.io.sequence import Sequence

    poses = Sequence(room).poses
    ahead = np.zeros(len(p), bool)
    for T in poses:  # the forward view looks along the camera's +z; 90 degrees: |x|, |y| <= z (+ a voxel)
        q = (p - T[:3, 3]) @ T[:3, :3]
        ahead |= (q[:, 2] > 0) & (np.abs(q[:, 0]) <= q[:, 2] + 2 * H) & (np.abs(q[:, 1]) <= q[:, 2] + 2 * H)
    assert len(p) > 100 and ahead.all()
    assert pred.class_names == ["empty"] and set(np.unique(pred.labels)) <= {0, 254, 255}
    assert json.loads((out / "baseline.json").read_text())["views"] == ["view_04_az000_mid"]


def test_local_box_centred_and_standing_on_the_floor():
    """Camera at (0.3, -0.2, 1.45): 60 x 60 x 36 voxels, horizontally centred on it; a floor layer at lattice
    z = -1 (plus a stray voxel below, too few to count) puts the box's bottom on that layer."""
    labels = np.full((80, 80, 40), 255, np.uint8)
    labels[:, :, 5] = 254  # z index 5 - 6 = -1
    labels[3, 3, 0] = 254  # one stray voxel at z = -6
    g = Grid(labels, index_to_center(np.array([-40, -40, -6]), H), H, ["empty"])
    T = np.eye(4)
    T[:3, 3] = (0.3, -0.2, 1.45)
    box = local_box(T, g)
    assert box.shape == (60, 60, 36)
    centre = index_to_center(box.index0, H)[:2] + (np.array(box.shape[:2]) - 1) / 2 * H
    assert np.all(np.abs(centre - T[:2, 3]) <= H / 2 + 1e-9)
    assert box.index0[2] == -1
    assert local_box(T, g, vertical="camera").index0[2] == round(1.45 / H - 18)


def test_single_pano_frames_and_per_frame_scores(room, tmp_path, cli):
    """Each frame alone in its box; the union merges them; per_frame.csv equals the frames scored against the
    ground truth cut to their box by a second route (evaluation.align.resample_onto)."""
    first = tmp_path / "p"
    assert cli(["baselines", "run", "persp-tsdf", room, first, "--quiet", "--noise", "0"])[0] == 0
    gt_path = first / "prediction.npz"  # a stand-in ground truth: the scores' bookkeeping is what is checked
    out = tmp_path / "s"
    code, so, err = cli(["baselines", "run", "single-pano", room, out, "--quiet", "--gt", gt_path, "--box",
                         "3.2,3.2,2.4"])
    assert code == 0, err
    frames = sorted((out / "frames").glob("*.npz"))
    assert [f.stem for f in frames] == ["000000", "000001", "000002", "000003"]
    gt = read_grid(gt_path)
    rows = (out / "per_frame.csv").read_text().splitlines()
    assert rows[0] == "frame,iou,miou,miou_present" and len(rows) == 5
    for f, row in zip(frames, rows[1:]):
        g = read_grid(f)
        assert g.labels.shape == (40, 40, 30)
        cut = Grid(resample_onto(gt, g), g.origin, H, gt.class_names)
        r = evaluate([(g, cut)], "eval8")["freeocc"]
        assert [float(x) for x in row.split(",")[1:3]] == pytest.approx([r.iou, r.miou], abs=1e-3)
    union = read_grid(out / "prediction.npz")
    for f in frames:  # every frame's occupied voxels are occupied in the union
        g = read_grid(f)
        assert np.all(np.isin(np.round(occupied_centres(g) / H), np.round(occupied_centres(union) / H)).all(axis=1))
    doc = json.loads((out / "baseline.json").read_text())
    assert doc["box_voxels"] == [40, 40, 30] and doc["per_frame"]["classes"] == "eval8"
    assert "per frame in its box" in so


@pytest.mark.parametrize("argv, expect", [
    (["persp-tsdf", "{room}", "{t}/o", "--box", "1,2"], "--box"),
    (["nosuch", "{room}", "{t}/o"], "NAME"),
    (["single-pano", "{t}/nosuch", "{t}/o"], "not found"),
    (["single-pano", "{room}", "{t}/o", "--gt", "{t}/no.npz"], "not found"),
    (["persp-tsdf", "{room}", "{room}"], "input"),
    (["forward-only", "{room}", "{t}/o", "--gt", "{room}/meta.json"], "panovocc eval"),
    (["single-pano", "{room}", "{t}/o", "--box", "1e9,1e9,1e9"], "GiB of memory"),  # estimated before any frame
    (["single-pano", "{room}", "{t}/o", "--box", "1e300,1,1"], "--box"),
    (["single-pano", "{room}", "{t}/o", "--gt", "{t}/g.npz", "--classes", ""], "empty class list"),
])
def test_bad_inputs_write_nothing(room, tmp_path, cli, argv, expect, monkeypatch):
    from panovocc_cli.geometry.lattice import index_to_center
    from panovocc_cli.io.grid import write_grid

    write_grid(tmp_path / "g.npz", Grid(np.ones((4, 4, 4), np.uint8), index_to_center(np.zeros(3, np.int64), H), H,
                                        ["empty", "wall"]))
    import panovocc_cli.baselines.single_pano as sp
    monkeypatch.setattr(sp, "single_pano", lambda *a, **k: (_ for _ in ()).throw(AssertionError("mapped a frame")))
    # (every refusal comes before the first frame is mapped)
    before = sorted(p.name for p in room.rglob("*"))
    code, _, err = cli(["baselines", "run", *[a.format(room=room, t=tmp_path) for a in argv], "--quiet"])
    assert code == 2 and expect.lower() in err.lower() and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists() and sorted(p.name for p in room.rglob("*")) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.npz"]


@pytest.mark.parametrize("fit", ["se3", "se3-pose"])
def test_poses_align_undoes_a_rigid_motion_of_the_trajectory(room, tmp_path, cli, fit):
    """--poses FILE --poses-align se3 (the benchmark's SLAM rows) or se3-pose (the whole poses): a trajectory given
    in another world frame (the true poses moved rigidly) maps to the same grid as the true poses; without alignment
    it does not."""
    from panovocc_cli.io.poses import write_poses
    from panovocc_cli.io.sequence import Sequence

    c, s = math.cos(0.7), math.sin(0.7)
    M = np.array([[c, -s, 0, 1.5], [s, c, 0, -0.4], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    moved = tmp_path / "moved.txt"
    write_poses(moved, M @ Sequence(room).poses)
    common = ["--quiet", "--segmenter", "none"]
    assert cli(["baselines", "run", "forward-only", room, tmp_path / "ref"] + common)[0] == 0
    code, _, err = cli(["baselines", "run", "forward-only", room, tmp_path / "al", "--poses", moved,
                        "--poses-align", fit] + common)
    assert code == 0, err
    assert cli(["baselines", "run", "forward-only", room, tmp_path / "raw", "--poses", moved] + common)[0] == 0
    ref, al, raw = (read_grid(tmp_path / n / "prediction.npz") for n in ("ref", "al", "raw"))
    occ = {n: {tuple(v) for v in np.round(occupied_centres(g) / H).astype(int)} for n, g in
           (("ref", ref), ("al", al), ("raw", raw))}
    assert len(occ["ref"]) > 100
    assert len(occ["ref"] ^ occ["al"]) <= 0.01 * len(occ["ref"])  # Umeyama's float round-off may move a voxel
    assert len(occ["ref"] & occ["raw"]) < 0.5 * len(occ["ref"])
