"""A ROS 1 / ROS 2 recording of a panoramic RGB-D camera -> toolkit sequence (``panovocc convert rosbag``).

Two passes over the bag (:mod:`panovocc_cli.io.rosbag`): the first reads every message time of the image
topics and every pose (a pose topic or ``/tf`` + ``/tf_static``); frames are then made by pairing each
depth image with the colour image nearest in time, one to one, within ``max_dt`` (a tie goes to the earlier
image), and giving the pair the camera pose at the depth image's time (interpolated between the two pose
samples around it, each within ``max_dt``). The second pass decodes only the paired images and writes the
frames in time order. What was paired and what was dropped, and why, goes into ``meta.json`` (``"rosbag"``)
and the command's report.

Conventions: the images are ERP panoramas (W = 2 H) in the toolkit's convention (the centre column looks
along the camera's +z; row 0 is the zenith). The pose is the camera's in the world frame (``T_world_cam``):
with ``camera_frame="optical"`` the pose's frame is already OpenCV-like (x right, y down, z forward, REP 103's
``*_optical_frame``); with ``"body"`` it is a ROS body frame (x forward, y left, z up) and is turned into
the optical one here. The world frame is the pose's parent (``map``/``odom``: +Z up, as the toolkit's).
Depth: ``radial`` (distance along the ray, the toolkit's) or ``cube-z`` (each pixel's planar depth on the
cube face its ray passes through, as a panorama stitched from six 90-degree depth cameras gives; converted to
radial); written as millimetre PNGs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError
from ..io.rosbag import IMAGE_TYPES, POSE_TYPES, STAMPS, TF_TOPICS, TF_TYPE

DEPTH_KINDS = ("radial", "cube-z")
DEPTH_UNITS = ("auto", "mm", "m")
CAMERA_FRAMES = ("optical", "body")
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""p_body = R_BODY_OPTICAL @ p_optical (REP 103: body x forward, y left, z up; optical x right, y down, z forward)."""


@dataclass
class ConvertRosbagConfig:
    """Options of ``panovocc convert rosbag``."""

    bag: Path = option(argument=True, metavar="BAG", help="A ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml).")
    out: Path = option(argument=True, metavar="SEQ", help="Sequence folder to write (meta.json, rgb/, depth/, poses.txt).")
    rgb: str = option(help="Topic of the ERP colour images (sensor_msgs/Image or CompressedImage).")
    depth: str = option(help="Topic of the ERP depth images (16UC1 / 32FC1 Image, or a 16-bit PNG CompressedImage).")
    poses: str | None = option(None, help="Topic of the camera poses (PoseStamped, PoseWithCovarianceStamped, "
                                          "TransformStamped or Odometry); or give --tf.", show_default=False)
    tf: str | None = option(None, metavar="PARENT:CHILD", help="Take the camera pose from /tf and /tf_static: the "
                                                             "transform from frame PARENT (the world) to CHILD (the camera).",
                            show_default=False)
    labels: str | None = option(None, help="Topic of per-pixel class id images (mono8 / mono16 / 16UC1), optional.",
                                show_default=False)
    class_names: str | None = option(None, help="Comma-separated class names of the label ids, id 0 first "
                                                "(\"unlabeled,wall,floor,...\"); needed with --labels.",
                                     show_default=False)
    depth_units: str = option("auto", choices=DEPTH_UNITS,
                              help="Depth units: auto (16-bit images in mm, float images in m), mm or m.")
    depth_kind: str = option("radial", choices=DEPTH_KINDS,
                             help="radial (distance along the ray) or cube-z (planar depth of the cube face the ray "
                                  "passes through, a panorama stitched from six depth cameras).")
    camera_frame: str = option("optical", choices=CAMERA_FRAMES,
                               help="The pose's camera frame: optical (x right, y down, z forward) or body (x forward, "
                                    "y left, z up).")
    max_dt: float = option(0.02, min=0.0, help="Seconds: the largest time difference of a depth image and the colour "
                                               "image, label image or pose paired with it.")
    stamp: str = option("header", choices=STAMPS, help="Message times: header (header.stamp) or bag (receive time).")
    width: int = option(0, min=0, even=True, help="Resize panoramas to this width (even; 0 = keep).")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous panovocc sequence in SEQ (never any other folder).")


def cube_z_to_radial(W: int, H: int) -> np.ndarray:
    """(H, W) float64 factors turning cube-face planar depth into radial depth: ``1 / max(|dx|, |dy|, |dz|)`` of
    each pixel's unit ray (the planar depth on the face the ray passes through is ``r * max(|d|)``)."""
    from ..geometry.erp import ray_directions

    d = ray_directions(W, H)
    return 1.0 / np.abs(d).max(axis=2)


def pair_nearest(t_a: np.ndarray, t_b: np.ndarray, max_dt_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs of times: each of ``t_a`` with the nearest of ``t_b`` within ``max_dt_ns`` (a tie to the
    earlier; :func:`io.poses.match_timestamps`), and where two of ``t_a`` chose the same ``t_b`` only the closer
    one (the earlier on a tie) keeps it. Returns index arrays (k,) int64 into ``t_a`` and ``t_b``, in ``t_a`` order."""
    from ..io.poses import match_timestamps

    a = np.asarray(t_a, np.int64)
    b = np.asarray(t_b, np.int64)
    if not len(a) or not len(b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    base = min(a.min(), b.min())  # seconds of a common origin keep float64 exact to the nanosecond
    ia, ib = match_timestamps((a - base).astype(np.float64), (b - base).astype(np.float64), float(max_dt_ns))
    dt = np.abs(a[ia] - b[ib])
    order = np.lexsort((a[ia], dt))  # closest first, then earlier
    seen, keep = set(), []
    for k in order:
        if int(ib[k]) not in seen:
            seen.add(int(ib[k]))
            keep.append(k)
    keep = np.sort(np.asarray(keep, np.int64))
    return ia[keep], ib[keep]


def _scan(bag, cfg: ConvertRosbagConfig):
    """First pass: the image topics' times (ns, with their bag order) and the pose source."""
    from ..io.rosbag import PoseSeries, TfTree, pose_of, stamp_ns

    types = {"rgb": bag.require(cfg.rgb, IMAGE_TYPES, "--rgb"), "depth": bag.require(cfg.depth, IMAGE_TYPES, "--depth")}
    if cfg.labels is not None:
        types["labels"] = bag.require(cfg.labels, IMAGE_TYPES, "--labels")
    topics = {cfg.rgb: "rgb", cfg.depth: "depth"} | ({cfg.labels: "labels"} if cfg.labels else {})
    if len(topics) != len(types):
        raise PanovoccError("--rgb, --depth and --labels must be three different topics")
    series, tree = None, None
    extra = []
    if cfg.poses is not None:
        ptype = bag.require(cfg.poses, POSE_TYPES, "--poses")
        series = PoseSeries()
        extra = [cfg.poses]
    else:
        tree = TfTree()
        have = bag.topics()
        extra = [t for t in TF_TOPICS if have.get(t) == TF_TYPE]
        if not extra:
            raise PanovoccError("--tf needs /tf or /tf_static (tf2_msgs/TFMessage) in the bag; none found", bag.path)
    times = {k: [] for k in types}
    for topic, t_bag, msg in bag.messages(list(topics) + extra):
        if topic in topics:
            times[topics[topic]].append(stamp_ns(msg, t_bag, cfg.stamp))
        elif series is not None:
            try:
                series.add(stamp_ns(msg, t_bag, cfg.stamp), pose_of(msg, ptype))
            except ValueError as e:
                raise PanovoccError(f"--poses {cfg.poses}: message at {t_bag} ns: {e}", bag.path) from None
        else:
            try:
                tree.add(msg, t_bag, topic == "/tf_static", cfg.stamp)
            except ValueError as e:
                raise PanovoccError(f"{topic}: message at {t_bag} ns: {e}", bag.path) from None
    if series is not None:
        series.finish()
        if not series.times:
            raise PanovoccError(f"--poses topic {cfg.poses} holds no messages", bag.path)
    else:
        tree.finish()
    for k, topic in (("rgb", cfg.rgb), ("depth", cfg.depth)):
        if not times[k]:
            raise PanovoccError(f"--{k} topic {topic} holds no messages", bag.path)
    return types, {k: np.asarray(v, np.int64) for k, v in times.items()}, series, tree


def plan_frames(times: dict, pose_at, max_dt_ns: int) -> dict:
    """The frames: depth images paired with colour (and label) images and a pose.

    Parameters
    ----------
    times : "rgb", "depth" (and "labels") -> (n,) int64 ns, in bag order
    pose_at : callable (t ns) -> (4, 4) T_world_cam or None

    Returns
    -------
    dict: ``frames`` [(depth index, rgb index, label index or None, t ns, T (4, 4))] in time order, and the
    report: ``depth``, ``rgb``, ``labels`` counts, ``paired``, ``unpaired_depth``, ``unpaired_rgb``,
    ``no_labels``, ``no_pose``, ``dt_median_ms``, ``dt_max_ms``.
    """
    td, tr = times["depth"], times["rgb"]
    idx_d, idx_r = pair_nearest(td, tr, max_dt_ns)
    lab = {}
    if "labels" in times:
        ld, ll = pair_nearest(td, times["labels"], max_dt_ns)
        lab = dict(zip(ld.tolist(), ll.tolist()))
    frames, no_pose, no_labels, dts = [], 0, 0, []
    for d, r in sorted(zip(idx_d.tolist(), idx_r.tolist()), key=lambda p: (td[p[0]], p[0])):
        if "labels" in times and d not in lab:
            no_labels += 1
            continue
        T = pose_at(int(td[d]))
        if T is None:
            no_pose += 1
            continue
        frames.append((d, r, lab.get(d), int(td[d]), T))
        dts.append(abs(int(td[d]) - int(tr[r])))
    return {"frames": frames, "depth": int(len(td)), "rgb": int(len(tr)),
            "labels": int(len(times.get("labels", ()))), "paired": int(len(idx_d)),
            "unpaired_depth": int(len(td) - len(idx_d)), "unpaired_rgb": int(len(tr) - len(idx_r)),
            "no_labels": no_labels, "no_pose": no_pose,
            "dt_median_ms": float(np.median(dts) / 1e6) if dts else float("nan"),
            "dt_max_ms": float(np.max(dts) / 1e6) if dts else float("nan")}


def _class_names(cfg: ConvertRosbagConfig) -> list[str]:
    from ..classes import canonical_name

    if cfg.labels is None:
        if cfg.class_names is not None:
            raise PanovoccError("--class-names names the ids of --labels; give --labels too")
        return ["unlabeled"]
    if not cfg.class_names:
        raise PanovoccError("--labels needs --class-names (the names of the label ids, id 0 first: "
                            "\"unlabeled,wall,floor,...\")")
    names = [canonical_name(n) for n in cfg.class_names.split(",")]
    if any(not n for n in names) or len(set(names)) != len(names):
        raise PanovoccError(f"--class-names: expected distinct non-empty names, got {cfg.class_names!r}")
    return names


def run_convert_rosbag(cfg: ConvertRosbagConfig) -> dict:
    """Convert ``cfg.bag`` into the sequence ``cfg.out``; returns the pairing report (see :func:`plan_frames`)
    with ``frames``, ``width``, ``height``."""
    import cv2
    from tqdm import tqdm

    from ..io.atomic import atomic_dir, check_output
    from ..io.images import write_png
    from ..io.rosbag import Bag, color_image, depth_image, label_image
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from ..io.sequence import SequenceMeta, frame_images, write_meta, write_sequence_poses

    cfg = validate_config(cfg)
    if (cfg.poses is None) == (cfg.tf is None):
        raise PanovoccError("give the camera poses by one of --poses TOPIC or --tf PARENT:CHILD")
    chain_ends = None
    if cfg.tf is not None:
        parts = cfg.tf.split(":")
        if len(parts) != 2 or not all(p.strip() for p in parts):
            raise PanovoccError(f"--tf: expected PARENT:CHILD (two frame names), got {cfg.tf!r}")
        chain_ends = (parts[0].strip(), parts[1].strip())
    names = _class_names(cfg)
    check_output(cfg.out, "sequence", cfg.overwrite, inputs=(cfg.bag,))
    max_dt_ns = int(round(cfg.max_dt * 1e9))
    A = np.eye(4)
    if cfg.camera_frame == "body":
        A[:3, :3] = R_BODY_OPTICAL
    with Bag(cfg.bag) as bag:
        types, times, series, tree = _scan(bag, cfg)
        if tree is not None:
            chain = tree.path(*chain_ends)

            def pose_at(t):
                T = tree.lookup(chain, t, max_dt_ns)
                return None if T is None else T @ A
        else:
            def pose_at(t):
                T = series.at(t, max_dt_ns)
                return None if T is None else T @ A
        plan = plan_frames(times, pose_at, max_dt_ns)
        frames = plan.pop("frames")
        if not frames:
            raise PanovoccError(f"no frame: {plan['paired']} depth images paired with a colour image within "
                                f"--max-dt {cfg.max_dt} s, {plan['no_pose']} of them without a pose within it"
                                + (f", {plan['no_labels']} without a label image" if cfg.labels else ""), cfg.bag)
        want = {"depth": {f[0]: k for k, f in enumerate(frames)}, "rgb": {f[1]: k for k, f in enumerate(frames)},
                "labels": {f[2]: k for k, f in enumerate(frames) if f[2] is not None}}
        topic_key = {cfg.rgb: "rgb", cfg.depth: "depth"} | ({cfg.labels: "labels"} if cfg.labels else {})
        seen = {k: 0 for k in topic_key.values()}
        pending: dict[int, dict] = {}
        size = None
        factor = None
        with atomic_dir(cfg.out) as tmp:
            for sub in ("rgb", "depth") + (("semantic",) if cfg.labels else ()):
                (tmp / sub).mkdir()
            bar = tqdm(total=len(frames), desc="convert", unit="frame", disable=not cfg.progress)
            for topic, _, msg in bag.messages(list(topic_key)):
                key = topic_key[topic]
                n = seen[key]
                seen[key] += 1
                k = want[key].get(n)
                if k is None:
                    continue
                if key == "rgb":
                    img = color_image(msg, types["rgb"], topic, bag.path)
                elif key == "depth":
                    img = depth_image(msg, types["depth"], topic, bag.path, cfg.depth_units)
                else:
                    img = label_image(msg, types["labels"], topic, bag.path)
                    if img.size and int(img.max()) >= len(names):
                        raise PanovoccError(f"topic {topic}: label id {int(img.max())} but --class-names has "
                                            f"{len(names)} names", bag.path)
                h, w = img.shape[:2]
                if w != 2 * h:
                    raise PanovoccError(f"topic {topic}: image {w}x{h} is not an ERP panorama (expected width = "
                                        "2 x height)", bag.path)
                if cfg.width and cfg.width != w:
                    wh = (cfg.width, cfg.width // 2)
                    img = cv2.resize(img, wh, interpolation=cv2.INTER_AREA if key == "rgb" else cv2.INTER_NEAREST)
                if size is None:
                    size = img.shape[:2]
                elif img.shape[:2] != size:
                    raise PanovoccError(f"topic {topic}: image {img.shape[1]}x{img.shape[0]}, earlier images "
                                        f"{size[1]}x{size[0]} (pass --width to resize all)", bag.path)
                got = pending.setdefault(k, {})
                got[key] = img
                if len(got) == (3 if frames[k][2] is not None else 2):
                    depth = got["depth"]
                    if cfg.depth_kind == "cube-z":
                        if factor is None:
                            factor = cube_z_to_radial(size[1], size[0])
                        depth = (depth * factor).astype(np.float32)
                    for path, image in frame_images(tmp, k, got["rgb"], depth, got.get("labels")):
                        write_png(path, image)
                    del pending[k]
                    bar.update(1)
            bar.close()
            if pending:  # a message counted in the first pass that the second did not give back
                raise PanovoccError(f"{len(pending)} paired frames were not found again in the bag", cfg.bag)
            H, W = size
            meta = SequenceMeta(width=W, height=H, frames=len(frames), camera="erp", class_names=names,
                                extra={"rosbag": {"bag": str(cfg.bag), "rgb": cfg.rgb, "depth": cfg.depth,
                                                  "poses": cfg.poses, "tf": cfg.tf, "labels": cfg.labels,
                                                  "stamp": cfg.stamp, "depth_kind": cfg.depth_kind,
                                                  "camera_frame": cfg.camera_frame, "pairing": plan,
                                                  "stamps_ns": [f[3] for f in frames]}})
            write_meta(tmp, meta)
            write_sequence_poses(tmp, np.stack([f[4] for f in frames]))
            write_run_config(tmp / CONFIG_NAME, cfg)
    return plan | {"frames": len(frames), "width": W, "height": H}
