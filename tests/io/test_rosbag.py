"""``convert rosbag``: ROS 2 and ROS 1 bags written here with ``rosbags`` itself (raw and compressed images, a
pose topic, /tf chains, labels), read back into a sequence; the pairing by time, the pose interpolation, and
one line with exit 2 for a bad bag, missing topics and wrong encodings."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from box_room import box_depth  # noqa: E402
from cli_helpers import run_cli, snapshot  # noqa: E402

pytest.importorskip("rosbags")

from panovocc_cli.datasets.rosbag import R_BODY_OPTICAL, cube_z_to_radial, pair_nearest  # noqa: E402
from panovocc_cli.geometry.poses import look_at  # noqa: E402
from panovocc_cli.io.poses import read_poses  # noqa: E402
from panovocc_cli.io.rosbag import quat_xyzw_to_rot  # noqa: E402
from panovocc_cli.io.sequence import Sequence  # noqa: E402

W = 64
SEC = 1_000_000_000
LO, HI = np.array([-2.3, -1.6, -1.4]), np.array([2.9, 2.1, 1.3])


def poses(n=4):
    return [look_at([0.3 * k, 0.1 * k, 0.05 * k], [np.cos(0.7 * k), np.sin(0.7 * k), 0.05]) for k in range(n)]


def quat(R):
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()  # x y z w


class BagWriter:
    """A small ROS 1 or ROS 2 bag of typed messages (rosbags' own writer and typestore)."""

    def __init__(self, path: Path, ros: int):
        from rosbags.typesys import Stores, get_typestore

        self.ros = ros
        self.ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.ts.types:  # Noetic's store lacks it: register its definition
            from rosbags.typesys import get_types_from_msg

            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
        if ros == 1:
            from rosbags.rosbag1 import Writer

            self.w = Writer(path)
        else:
            from rosbags.rosbag2 import Writer

            self.w = Writer(path, version=9)
        self.w.open()
        self.conns = {}
        self.T = self.ts.types

    def header(self, t, frame="cam"):
        Time = self.T["builtin_interfaces/msg/Time"]
        kw = {"seq": 0} if self.ros == 1 else {}
        return self.T["std_msgs/msg/Header"](**kw, stamp=Time(sec=t // SEC, nanosec=t % SEC), frame_id=frame)

    def write(self, topic, msg, t_bag):
        typ = msg.__msgtype__
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, typ, typestore=self.ts)
        raw = self.ts.serialize_ros1(msg, typ) if self.ros == 1 else self.ts.serialize_cdr(msg, typ)
        self.w.write(self.conns[topic], int(t_bag), raw)

    def image(self, topic, t, a, enc, t_bag=None):
        a = np.ascontiguousarray(a)
        h, w = a.shape[:2]
        msg = self.T["sensor_msgs/msg/Image"](header=self.header(t), height=h, width=w, encoding=enc, is_bigendian=0,
                                               step=a.strides[0], data=a.view(np.uint8).reshape(-1))
        self.write(topic, msg, t if t_bag is None else t_bag)

    def compressed(self, topic, t, buf, fmt):
        msg = self.T["sensor_msgs/msg/CompressedImage"](header=self.header(t), format=fmt,
                                                         data=np.frombuffer(buf, np.uint8))
        self.write(topic, msg, t)

    def _pose(self, T):
        P = self.T["geometry_msgs/msg/Pose"]
        q = quat(T[:3, :3])
        return P(position=self.T["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                 orientation=self.T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))

    def pose(self, topic, t, T):
        self.write(topic, self.T["geometry_msgs/msg/PoseStamped"](header=self.header(t, "map"), pose=self._pose(T)), t)

    def tf(self, topic, t, parent, child, T):
        q = quat(T[:3, :3])
        tr = self.T["geometry_msgs/msg/Transform"](
            translation=self.T["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=self.T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
        ts = self.T["geometry_msgs/msg/TransformStamped"](header=self.header(t, parent), child_frame_id=child,
                                                           transform=tr)
        self.write(topic, self.T["tf2_msgs/msg/TFMessage"](transforms=[ts]), t)

    def close(self):
        self.w.close()


def frames_data(n=4):
    rng = np.random.default_rng(0)
    out = []
    for T in poses(n):
        rgb = rng.integers(0, 255, (W // 2, W, 3), dtype=np.uint8)
        d = box_depth(W, T, LO, HI)
        out.append((T, rgb, np.rint(d * 1000).astype(np.uint16)))
    return out


def smooth_rgb(k):
    """A panorama JPEG keeps nearly exactly: red along the columns, green down the rows, blue constant."""
    v, u = np.mgrid[0:W // 2, 0:W]
    return np.stack([u * 255 // W, v * 255 // (W // 2), np.full_like(u, 40 + 10 * k)], axis=2).astype(np.uint8)


def run(capsys, *argv):
    return run_cli(capsys, list(argv))


@pytest.fixture(scope="module")
def ros2_bag(tmp_path_factory):
    """ROS 2: rgb8 + 16UC1 depth 3 ms apart, a pose topic at the depth stamps, one extra unpaired colour image
    and one depth image with no colour image near it."""
    path = tmp_path_factory.mktemp("ros2") / "bag"
    b = BagWriter(path, 2)
    data = frames_data()
    for k, (T, rgb, mm) in enumerate(data):
        t = (10 + k) * SEC
        b.image("/cam/rgb", t + 3_000_000, rgb, "rgb8")
        b.image("/cam/depth", t, mm, "16UC1")
        b.pose("/cam/pose", t, T)
    b.image("/cam/rgb", 20 * SEC, data[0][1], "rgb8")  # no depth near it
    b.image("/cam/depth", 30 * SEC, data[0][2], "16UC1")  # no colour near it
    b.close()
    return path, data


def test_ros2_raw_images_and_pose_topic(ros2_bag, tmp_path, capsys):
    path, data = ros2_bag
    seq = tmp_path / "seq"
    code, out, err = run(capsys, "convert", "rosbag", path, seq, "--rgb", "/cam/rgb", "--depth", "/cam/depth",
                         "--poses", "/cam/pose", "--quiet")
    assert code == 0, err
    assert "4 frames 64x32" in out and "unpaired: 1 depth, 1 colour" in out and "median 3.0 ms" in out
    s = Sequence(seq)
    assert len(s) == 4
    for k, (T, rgb, mm) in enumerate(data):
        assert np.array_equal(s.rgb(k), rgb)
        assert np.array_equal(np.rint(s.depth(k) * 1000).astype(np.uint16), mm)
        assert np.allclose(s.poses[k], T, atol=1e-9)
    import json

    meta = json.loads((seq / "meta.json").read_text())
    assert meta["rosbag"]["pairing"]["paired"] == 4 and meta["rosbag"]["stamps_ns"][0] == 10 * SEC
    assert (seq / "config.json").is_file()


def test_ros1_compressed_images_tf_chain_and_body_frame(tmp_path, capsys):
    """ROS 1: JPEG colour, image_transport compressedDepth depth, PNG labels, the pose from /tf (map -> base,
    dynamic, sampled between frames: interpolated) and /tf_static (base -> cam, a body frame)."""
    import cv2

    path = tmp_path / "rec.bag"
    b = BagWriter(path, 1)
    data = frames_data(3)
    T_base_cam = np.eye(4)
    T_base_cam[:3, 3] = (0.1, 0.0, 0.3)
    b.tf("/tf_static", 1 * SEC, "base", "cam", T_base_cam)
    want = []
    for k, (T, rgb, mm) in enumerate(data):
        t = (10 + k) * SEC
        A = np.eye(4)
        A[:3, :3] = R_BODY_OPTICAL  # T_body_optical
        T_world_body = T @ np.linalg.inv(A)
        T_map_base = T_world_body @ np.linalg.inv(T_base_cam)
        # samples 5 ms before and after the image: the translation halfway, the rotation the same
        for dt, shift in ((-5_000_000, -0.01), (5_000_000, 0.01)):
            S = T_map_base.copy()
            S[0, 3] += shift
            b.tf("/tf", t + dt, "map", "base", S)
        want.append(T)
        rgb = smooth_rgb(k)
        b.compressed("/rgb/compressed", t, cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes(),
                     "rgb8; jpeg compressed bgr8")
        b.compressed("/depth/compressedDepth", t, bytes(12) + cv2.imencode(".png", mm)[1].tobytes(),
                     "16UC1; compressedDepth png")
        lab = np.full((W // 2, W), k + 1, np.uint8)
        b.compressed("/labels", t, cv2.imencode(".png", lab)[1].tobytes(), "mono8; png compressed")
    b.close()
    seq = tmp_path / "seq"
    code, out, err = run(capsys, "convert", "rosbag", path, seq, "--rgb", "/rgb/compressed", "--depth",
                         "/depth/compressedDepth", "--tf", "map:cam", "--camera-frame", "body", "--labels", "/labels",
                         "--class-names", "unlabeled,wall,floor,chair", "--quiet")
    assert code == 0, err
    s = Sequence(seq)
    assert len(s) == 3 and s.meta.class_names == ["unlabeled", "wall", "floor", "chair"]
    for k, (T, rgb, mm) in enumerate(data):
        assert np.allclose(s.poses[k], want[k], atol=1e-9)
        assert np.array_equal(np.rint(s.depth(k) * 1000).astype(np.uint16), mm)
        got, ref = s.rgb(k).astype(int), smooth_rgb(k).astype(int)
        assert np.abs(got - ref).mean() < 3 < np.abs(got[:, :, ::-1] - ref).mean()  # JPEG: lossy; colour order kept
        assert np.all(s.labels(k) == k + 1)


def test_pairing_is_one_to_one_and_nearest():
    a = np.array([0, 10, 12, 100]) * 1_000_000
    b = np.array([11, 13, 200]) * 1_000_000
    ia, ib = pair_nearest(a, b, 5_000_000)
    # 10 and 12 both want 11 (12 is 1 ms away, 10 is 1 ms away: the tie goes to the earlier); 12 then has none
    assert ia.tolist() == [1] and ib.tolist() == [0]
    ia, ib = pair_nearest(np.array([10, 12]) * 1_000_000, np.array([11, 12]) * 1_000_000, 5_000_000)
    assert ia.tolist() == [0, 1] and ib.tolist() == [0, 1]


def test_cube_z_depth_and_quaternions():
    f = cube_z_to_radial(64, 32)
    assert f.min() >= 1.0 and f.max() <= np.sqrt(3) + 1e-9
    assert np.isclose(f[16, 32], 1.0, atol=0.01)  # the centre column at the equator: along +z, radial = z
    R = quat_xyzw_to_rot(quat(look_at([0, 0, 0], [0.3, 0.8, 0.1])[:3, :3]))
    assert np.allclose(R, look_at([0, 0, 0], [0.3, 0.8, 0.1])[:3, :3], atol=1e-12)
    # the body frame: the optical +z (forward) is the body's +x
    assert np.allclose(R_BODY_OPTICAL @ [0, 0, 1], [1, 0, 0]) and np.allclose(R_BODY_OPTICAL @ [0, 1, 0], [0, 0, -1])


def _bad_bag(tmp_path, enc="rgb8", size=(W // 2, W)):
    path = tmp_path / f"bad-{enc}"
    b = BagWriter(path, 2)
    T, rgb, mm = frames_data(1)[0]
    img = np.zeros(size + (3,), np.uint8) if enc != "16UC1" else np.zeros(size, np.uint16)
    b.image("/rgb", SEC, img if enc in ("rgb8", "16UC1") else np.zeros(size + (2,), np.uint8), enc)
    b.image("/depth", SEC, np.zeros(size, np.uint16) if size != (W // 2, W) else mm, "16UC1")
    b.pose("/pose", SEC, T)
    b.close()
    return path


@pytest.mark.parametrize("case", ["not_a_bag", "garbage_ros2", "missing_topic", "pose_type", "encoding", "yuv",
                                  "not_erp", "labels_without_names", "both_pose_sources", "no_tf", "nothing_paired", "truncated"])
def test_bad_bags_one_line_exit_2_nothing_written(case, tmp_path, capsys, ros2_bag):
    good, _ = ros2_bag
    topics = ["--rgb", "/cam/rgb", "--depth", "/cam/depth", "--poses", "/cam/pose"]
    bag = good
    if case == "not_a_bag":
        bag = tmp_path / "x.bag"
        bag.write_bytes(b"not a bag at all" * 10)
    elif case == "garbage_ros2":
        bag = tmp_path / "r2"
        bag.mkdir()
        (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    elif case == "truncated":  # the storage file cut short, as a copy interrupted mid-way leaves it
        import shutil

        bag = tmp_path / "cut"
        shutil.copytree(good, bag)
        db = next(bag.glob("*.db3"))
        db.write_bytes(db.read_bytes()[: db.stat().st_size // 3])
    elif case == "missing_topic":
        topics[1] = "/nope"
    elif case == "pose_type":
        topics[5] = "/cam/rgb"
    elif case == "encoding":
        topics[1] = "/cam/depth"  # a depth image as the colour topic: 16UC1 is not a colour encoding
        topics[3] = "/cam/rgb"
    elif case == "yuv":
        bag = _bad_bag(tmp_path, "yuv422")
        topics = ["--rgb", "/rgb", "--depth", "/depth", "--poses", "/pose"]
    elif case == "not_erp":
        bag = _bad_bag(tmp_path, "rgb8", (20, 30))
        topics = ["--rgb", "/rgb", "--depth", "/depth", "--poses", "/pose"]
    elif case == "labels_without_names":
        topics += ["--labels", "/cam/rgb"]
    elif case == "both_pose_sources":
        topics += ["--tf", "map:cam"]
    elif case == "no_tf":
        topics = topics[:4] + ["--tf", "map:cam"]
    elif case == "nothing_paired":
        topics += ["--max-dt", "0", "--stamp", "bag"]
    before = snapshot(good, bag)
    out = tmp_path / "seq"
    code, o, err = run(capsys, "convert", "rosbag", bag, out, *topics, "--quiet")
    assert code == 2, (o, err)
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    assert not out.exists()
    assert snapshot(good, bag) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".seq")]
