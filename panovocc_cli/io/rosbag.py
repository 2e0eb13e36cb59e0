"""ROS 1 (``.bag``) and ROS 2 (a folder with ``metadata.yaml``, SQLite3 or MCAP storage) recordings, read
through ``rosbags`` (no ROS installation); message contents converted to the toolkit's conventions here.

Messages read:

* images: ``sensor_msgs/msg/Image`` (encodings ``rgb8 bgr8 rgba8 bgra8 mono8`` for colour; ``16UC1``/``mono16``
  (millimetres by default) and ``32FC1`` (metres) for depth; ``mono8 mono16 16UC1`` for label ids) and
  ``sensor_msgs/msg/CompressedImage`` (``jpeg``/``png``; depth as a 16-bit PNG or image_transport's
  ``compressedDepth`` form: a 12-byte header, then a 16-bit PNG of millimetres);
* poses: ``geometry_msgs/msg/PoseStamped``, ``PoseWithCovarianceStamped``, ``TransformStamped``,
  ``nav_msgs/msg/Odometry`` (the pose of the message's child frame in its header frame), and
  ``tf2_msgs/msg/TFMessage`` on ``/tf`` and ``/tf_static`` (``--tf PARENT:CHILD``: the chain of transforms
  between the two frames, each interpolated at the image's time).

Times are nanoseconds: the message's ``header.stamp`` (``stamp="header"``) or the bag's receive time
(``stamp="bag"``). ROS quaternions are x-y-z-w; converted to rotation matrices at this boundary.
"""

from __future__ import annotations

from collections import defaultdict, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import PanovoccError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED)
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
              "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")
TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_TOPICS = ("/tf", "/tf_static")
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
LABEL_ENCODINGS = ("mono8", "mono16", "16UC1", "8UC1")
STAMPS = ("header", "bag")


def _rosbags():
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise PanovoccError("reading ROS bags needs rosbags: pip install 'panovocc[ros]' (make setup installs it)") \
            from None
    return AnyReader, AnyReaderError, Stores, get_typestore


def _why(e: Exception) -> str:
    """An exception as one line: its type and its message with the whitespace (line breaks) folded."""
    return f"{type(e).__name__}: {' '.join(str(e).split())}"


class Bag:
    """An open ROS 1 or ROS 2 recording (use as a context manager).

    path : a ROS 1 ``.bag`` file or a ROS 2 bag folder (``metadata.yaml`` and its storage files)
    """

    def __init__(self, path: str | Path):
        AnyReader, AnyReaderError, Stores, get_typestore = _rosbags()
        self.path = Path(path)
        if not self.path.exists():
            raise PanovoccError("bag not found (expected a ROS 1 .bag file or a ROS 2 bag folder)", self.path)
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise PanovoccError("not a ROS 2 bag folder (no metadata.yaml)", self.path)
        if self.path.is_file() and self.path.suffix != ".bag":
            raise PanovoccError("not a ROS 1 bag (expected a .bag file) nor a ROS 2 bag folder", self.path)
        self._errors = (AnyReaderError, KeyError, ValueError, OSError, EOFError, IndexError, AssertionError,
                        TypeError, AttributeError)
        try:
            self.reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self.reader.open()
        except self._errors as e:
            raise PanovoccError(f"cannot read the bag ({_why(e)})", self.path) from None
        except Exception as e:  # rosbags' own reader errors (Reader1/Reader2) and sqlite/mcap errors
            raise PanovoccError(f"cannot read the bag ({_why(e)})", self.path) from None

    def __enter__(self) -> "Bag":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        try:
            self.reader.close()
        except Exception:  # closing a half-opened reader
            pass

    def topics(self) -> dict[str, str]:
        """Topic -> message type (``sensor_msgs/msg/Image``) of every topic in the bag."""
        return {c.topic: c.msgtype for c in self.reader.connections}

    def require(self, topic: str, types: tuple[str, ...], what: str) -> str:
        """The message type of ``topic``; one line naming the topics there when it is missing or of another type."""
        topics = self.topics()
        if topic not in topics:
            shown = ", ".join(f"{t} ({m.split('/')[-1]})" for t, m in sorted(topics.items())) or "none"
            raise PanovoccError(f"{what} topic {topic} not in the bag (topics: {shown})", self.path)
        if topics[topic] not in types:
            raise PanovoccError(f"{what} topic {topic} is {topics[topic]}, expected "
                                f"{' or '.join(types)}", self.path)
        return topics[topic]

    def messages(self, topics):
        """``(topic, bag time ns, message)`` of the given topics, in bag-time order."""
        conns = [c for c in self.reader.connections if c.topic in set(topics)]
        if not conns:
            return
        try:
            for c, t, raw in self.reader.messages(connections=conns):
                yield c.topic, int(t), self.reader.deserialize(raw, c.msgtype)
        except self._errors as e:
            raise PanovoccError(f"cannot read a message ({_why(e)})", self.path) from None


def stamp_ns(msg, bag_ns: int, stamp: str = "header") -> int:
    """A message's time in nanoseconds: its ``header.stamp`` (when set, else the bag time) or the bag time."""
    if stamp == "header":
        h = getattr(msg, "header", None)
        if h is not None:
            ns = int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
            if ns > 0:
                return ns
    return int(bag_ns)


# ---------------------------------------------------------------------------------------------
# images


def _raw_image(msg, topic: str, path: Path) -> tuple[np.ndarray, str]:
    """(array, encoding) of a ``sensor_msgs/Image``: (H, W[, C]) of its pixel type, rows of ``step`` bytes."""
    enc = str(msg.encoding)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dtypes = {"rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4), "mono8": ("u1", 1),
              "8UC1": ("u1", 1), "mono16": ("u2", 1), "16UC1": ("u2", 1), "32FC1": ("f4", 1)}
    if enc not in dtypes:
        raise PanovoccError(f"topic {topic}: image encoding {enc!r} is not supported (expected one of "
                            f"{', '.join(dtypes)})", path)
    kind, ch = dtypes[enc]
    dt = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    data = np.asarray(msg.data, np.uint8)
    row = w * ch * dt.itemsize
    if h <= 0 or w <= 0 or step < row or data.size < step * h:
        raise PanovoccError(f"topic {topic}: image data of {data.size} bytes does not hold {h} rows of {step} bytes "
                            f"({w}x{h} {enc})", path)
    a = data[: step * h].reshape(h, step)[:, :row].copy().view(dt).reshape((h, w, ch) if ch > 1 else (h, w))
    return a.astype(dt.newbyteorder("=")), enc


def _decode(buf: bytes, flags, topic: str, path: Path) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(buf, np.uint8), flags)
    if img is None:
        raise PanovoccError(f"topic {topic}: compressed image data could not be decoded", path)
    return img


def color_image(msg, msgtype: str, topic: str, path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour image message."""
    import cv2

    if msgtype == COMPRESSED:
        img = _decode(bytes(msg.data), cv2.IMREAD_COLOR, topic, path)  # BGR
        return np.ascontiguousarray(img[:, :, ::-1])
    a, enc = _raw_image(msg, topic, path)
    if enc not in COLOR_ENCODINGS:
        raise PanovoccError(f"topic {topic}: encoding {enc!r} is not a colour image (expected "
                            f"{', '.join(COLOR_ENCODINGS)})", path)
    if enc == "mono8":
        return np.repeat(a[:, :, None], 3, axis=2)
    a = a[:, :, :3]
    return np.ascontiguousarray(a[:, :, ::-1] if enc.startswith("bgr") else a)


def depth_image(msg, msgtype: str, topic: str, path: Path, units: str = "auto") -> np.ndarray:
    """(H, W) float32 metres (0 = no measurement) of a depth image message.

    units : ``auto`` (16-bit images are millimetres, 32-bit float images metres), ``mm`` or ``m``
    """
    import cv2

    if msgtype == COMPRESSED:
        fmt = str(msg.format)
        buf = bytes(msg.data)
        if "compresseddepth" in fmt.lower().replace(" ", ""):  # image_transport: 12-byte config header, then PNG
            if len(buf) <= 12:
                raise PanovoccError(f"topic {topic}: compressedDepth message too short", path)
            buf = buf[12:]
        a = _decode(buf, cv2.IMREAD_UNCHANGED, topic, path)
        if a.ndim != 2 or a.dtype != np.uint16:
            raise PanovoccError(f"topic {topic}: compressed depth decodes to {a.dtype} with shape {a.shape}, expected "
                                "a one-channel 16-bit PNG", path)
        enc = "16UC1"
    else:
        a, enc = _raw_image(msg, topic, path)
        if enc not in DEPTH_ENCODINGS:
            raise PanovoccError(f"topic {topic}: encoding {enc!r} is not a depth image (expected "
                                f"{', '.join(DEPTH_ENCODINGS)})", path)
    scale = {"mm": 1e-3, "m": 1.0}.get(units, 1.0 if enc == "32FC1" else 1e-3)
    d = a.astype(np.float64) * scale
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    return d.astype(np.float32)


def label_image(msg, msgtype: str, topic: str, path: Path) -> np.ndarray:
    """(H, W) uint16 class ids of a label image message (0 = unlabeled)."""
    import cv2

    if msgtype == COMPRESSED:
        a = _decode(bytes(msg.data), cv2.IMREAD_UNCHANGED, topic, path)
        if a.ndim != 2 or a.dtype not in (np.uint8, np.uint16) or "png" not in str(msg.format).lower():
            raise PanovoccError(f"topic {topic}: compressed labels must be a one-channel 8- or 16-bit PNG, got "
                                f"{a.dtype} {a.shape} ({msg.format})", path)
        return a.astype(np.uint16)
    a, enc = _raw_image(msg, topic, path)
    if enc not in LABEL_ENCODINGS:
        raise PanovoccError(f"topic {topic}: encoding {enc!r} is not a label image (expected "
                            f"{', '.join(LABEL_ENCODINGS)})", path)
    return a.astype(np.uint16)


# ---------------------------------------------------------------------------------------------
# poses


def quat_xyzw_to_rot(q) -> np.ndarray:
    """(3, 3) float64 rotation of a ROS quaternion (x, y, z, w), normalised; a zero quaternion is refused."""
    x, y, z, w = (float(v) for v in q)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("zero or non-finite quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _matrix(position, orientation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_xyzw_to_rot((orientation.x, orientation.y, orientation.z, orientation.w))
    T[:3, 3] = (float(position.x), float(position.y), float(position.z))
    return T


def pose_of(msg, msgtype: str) -> np.ndarray:
    """(4, 4) float64: the pose a pose message carries (its child frame in its header frame)."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return _matrix(msg.pose.position, msg.pose.orientation)
    if msgtype in ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"):
        return _matrix(msg.pose.pose.position, msg.pose.pose.orientation)
    if msgtype == "geometry_msgs/msg/TransformStamped":
        return _matrix(msg.transform.translation, msg.transform.rotation)
    raise PanovoccError(f"message type {msgtype} carries no pose (expected {', '.join(POSE_TYPES)})")


def _slerp(R0: np.ndarray, R1: np.ndarray, a: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation, Slerp

    return Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R0, R1])))([a]).as_matrix()[0]


@dataclass
class PoseSeries:
    """Poses (4, 4) at times (ns), sorted; sampled by linear interpolation of the translation and slerp of
    the rotation between the two nearest samples around a time (or the nearest sample within ``max_gap_ns``
    when the time lies outside them)."""

    times: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    static: bool = False

    def add(self, t: int, T: np.ndarray) -> None:
        self.times.append(int(t))
        self.poses.append(np.asarray(T, np.float64))

    def finish(self) -> None:
        order = np.argsort(np.asarray(self.times, np.int64), kind="stable")
        self.times = [self.times[k] for k in order]
        self.poses = [self.poses[k] for k in order]

    def at(self, t: int, max_gap_ns: int) -> np.ndarray | None:
        """The pose at time ``t`` (ns), or None when no sample is within ``max_gap_ns`` of it (interpolating
        needs a sample on each side, each within ``max_gap_ns``)."""
        if not self.times:
            return None
        if self.static:
            return self.poses[-1]
        ts = np.asarray(self.times, np.int64)
        k = int(np.searchsorted(ts, t))
        if k < len(ts) and ts[k] == t:
            return self.poses[k]
        if 0 < k < len(ts) and t - ts[k - 1] <= max_gap_ns and ts[k] - t <= max_gap_ns:
            a = (t - ts[k - 1]) / (ts[k] - ts[k - 1])
            P0, P1 = self.poses[k - 1], self.poses[k]
            T = np.eye(4)
            T[:3, :3] = _slerp(P0[:3, :3], P1[:3, :3], float(a))
            T[:3, 3] = (1 - a) * P0[:3, 3] + a * P1[:3, 3]
            return T
        near = [j for j in (k - 1, k) if 0 <= j < len(ts) and abs(int(ts[j]) - t) <= max_gap_ns]
        if not near:
            return None
        j = min(near, key=lambda j: abs(int(ts[j]) - t))
        return self.poses[j]


class TfTree:
    """Transforms of ``/tf`` and ``/tf_static``: edges parent -> child with their time series."""

    def __init__(self):
        self.edges: dict[tuple[str, str], PoseSeries] = {}

    @staticmethod
    def _name(frame: str) -> str:
        return str(frame).lstrip("/")

    def add(self, msg, bag_ns: int, static: bool, stamp: str) -> None:
        for tr in msg.transforms:
            key = (self._name(tr.header.frame_id), self._name(tr.child_frame_id))
            s = self.edges.setdefault(key, PoseSeries(static=static))
            s.add(stamp_ns(tr, bag_ns, stamp), _matrix(tr.transform.translation, tr.transform.rotation))

    def finish(self) -> None:
        for s in self.edges.values():
            s.finish()

    def path(self, parent: str, child: str) -> list[tuple[tuple[str, str], bool]]:
        """The chain of edges from ``parent`` to ``child`` (each edge and whether it is walked backwards)."""
        parent, child = self._name(parent), self._name(child)
        nbr = defaultdict(list)
        for a, b in self.edges:
            nbr[a].append((b, (a, b), False))
            nbr[b].append((a, (a, b), True))
        prev = {parent: None}
        q = deque([parent])
        while q:
            f = q.popleft()
            if f == child:
                break
            for g, e, inv in nbr[f]:
                if g not in prev:
                    prev[g] = (f, e, inv)
                    q.append(g)
        if child not in prev:
            frames = sorted({f for e in self.edges for f in e})
            raise PanovoccError(f"no chain of transforms from {parent!r} to {child!r} in /tf and /tf_static "
                                f"(frames: {', '.join(frames) or 'none'})")
        chain = []
        f = child
        while prev[f] is not None:
            g, e, inv = prev[f]
            chain.append((e, inv))
            f = g
        return chain[::-1]

    def lookup(self, chain, t: int, max_gap_ns: int) -> np.ndarray | None:
        """T_parent_child at time ``t`` along ``chain`` (:meth:`path`), or None when an edge has no sample near it."""
        T = np.eye(4)
        for e, inv in chain:
            P = self.edges[e].at(t, max_gap_ns)
            if P is None:
                return None
            T = T @ (np.linalg.inv(P) if inv else P)
        return T
