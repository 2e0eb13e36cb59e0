"""A small PLY reader/writer in numpy (no extra dependency), enough for Replica's meshes.

Reads ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` files with any scalar vertex
properties and a face element holding one list property (``vertex_indices`` or ``vertex_index``)
plus scalar properties (Replica's ``object_id``). Binary faces of one fixed polygon size (Replica's
quads) are read with one structured dtype; mixed polygon sizes fall back to a per-face scan.
Writes binary little-endian files exactly like Replica's ``mesh_semantic.ply``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from .atomic import atomic_path

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass
class PlyElement:
    name: str
    count: int
    scalars: list[tuple[str, str]] = field(default_factory=list)  # (name, numpy type code)
    lists: list[tuple[str, str, str]] = field(default_factory=list)  # (name, count type, item type)
    order: list[str] = field(default_factory=list)  # property names in file order


@dataclass
class PlyMesh:
    """Contents of a PLY mesh.

    vertex : dict name -> (V,) array (e.g. x, y, z, nx, ny, nz, red, green, blue)
    faces : list of (F_k, n_k) int64 arrays, one per polygon size found (with ``face_rows``)
    face_rows : list of (F_k,) int64, positions of those faces in the file
    face : dict name -> (F,) array of the face element's scalar properties (e.g. object_id)
    """

    vertex: dict[str, np.ndarray]
    faces: list[np.ndarray]
    face_rows: list[np.ndarray]
    face: dict[str, np.ndarray]
    num_faces: int


def _parse_header(raw: bytes, path: Path) -> tuple[str, list[PlyElement], int]:
    if not raw.startswith(b"ply"):
        raise PanovoccError("not a PLY file (missing 'ply' magic)", path)
    end = raw.find(b"end_header")
    if end < 0:
        raise PanovoccError("PLY header has no end_header", path)
    nl = raw.find(b"\n", end)
    body = nl + 1 if nl >= 0 else len(raw)
    fmt = None
    elements: list[PlyElement] = []
    for line in raw[:end].decode("ascii", errors="replace").splitlines()[1:]:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        try:
            if parts[0] == "format":
                fmt = parts[1]
            elif parts[0] == "element":
                elements.append(PlyElement(parts[1], int(parts[2])))
            elif parts[0] == "property":
                el = elements[-1]
                if parts[1] == "list":
                    el.lists.append((parts[4], _TYPES[parts[2]], _TYPES[parts[3]]))
                    el.order.append(parts[4])
                else:
                    el.scalars.append((parts[2], _TYPES[parts[1]]))
                    el.order.append(parts[2])
        except (IndexError, KeyError, ValueError):
            raise PanovoccError(f"malformed PLY header line {line.strip()!r}", path) from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PanovoccError(f"unsupported PLY format {fmt!r}", path)
    return fmt, elements, body


def read_ply(path: str | Path) -> PlyMesh:
    """Read a PLY mesh (vertices with scalar properties; faces as polygons plus scalar properties)."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("PLY file not found", path)
    raw = path.read_bytes()
    fmt, elements, pos = _parse_header(raw, path)
    names = [e.name for e in elements]
    if "vertex" not in names or "face" not in names:
        raise PanovoccError("PLY needs 'vertex' and 'face' elements", path)
    if fmt == "ascii":
        return _read_ascii(raw[pos:], elements, path)
    end = "<" if fmt == "binary_little_endian" else ">"
    out_vertex: dict[str, np.ndarray] = {}
    out = None
    try:
        for el in elements:
            if el.name == "face":
                out, pos = _read_binary_faces(raw, pos, el, end, path)
                continue
            if el.lists:
                raise PanovoccError(f"element {el.name!r} has list properties; only 'face' may", path)
            dt = np.dtype([(n, end + t) for n, t in el.scalars])
            arr = np.frombuffer(raw, dtype=dt, count=el.count, offset=pos)
            pos += dt.itemsize * el.count
            if el.name == "vertex":
                out_vertex = {n: arr[n].astype(arr[n].dtype.newbyteorder("="), copy=True) for n, _ in el.scalars}
    except ValueError:
        raise PanovoccError("PLY file is truncated (fewer bytes than the header declares)", path) from None
    faces, rows, face_props, nf = out
    return PlyMesh(out_vertex, faces, rows, face_props, nf)


def _read_binary_faces(raw: bytes, pos: int, el: PlyElement, end: str, path: Path):
    lists = [l for l in el.lists if l[0] in _FACE_LISTS]
    if len(el.lists) != 1 or not lists:
        raise PanovoccError("face element must have exactly one list property 'vertex_indices' or 'vertex_index'",
                            path)
    lname, ctype, itype = lists[0]
    n = el.count
    if n == 0:
        return ([], [], {s: np.zeros(0, s_t) for s, s_t in el.scalars}, 0), pos
    first = int(np.frombuffer(raw, dtype=end + ctype, count=1, offset=_offset_of_list(el, pos))[0])
    fields = []
    for pname in el.order:
        if pname == lname:
            fields += [("__n", end + ctype), ("__idx", end + itype, (first,))]
        else:
            fields.append((pname, end + dict(el.scalars)[pname]))
    dt = np.dtype(fields)
    if pos + dt.itemsize * n <= len(raw):
        arr = np.frombuffer(raw, dtype=dt, count=n, offset=pos)
        if np.all(arr["__n"] == first):
            props = {s: arr[s].astype(arr[s].dtype.newbyteorder("=")) for s, _ in el.scalars}
            idx = arr["__idx"].astype(np.int64)
            return ([idx], [np.arange(n, dtype=np.int64)], props, n), pos + dt.itemsize * n
    # Mixed polygon sizes: scan face by face.
    sizes = {k: np.dtype(end + t).itemsize for k, t in el.scalars}
    csize, isize = np.dtype(ctype).itemsize, np.dtype(itype).itemsize
    props = {s: np.zeros(n, dtype=t) for s, t in el.scalars}
    polys: dict[int, list] = {}
    for f in range(n):
        for pname in el.order:
            if pname == lname:
                k = int(np.frombuffer(raw, dtype=end + ctype, count=1, offset=pos)[0])
                pos += csize
                idx = np.frombuffer(raw, dtype=end + itype, count=k, offset=pos)
                pos += isize * k
                polys.setdefault(k, []).append((f, idx))
            else:
                props[pname][f] = np.frombuffer(raw, dtype=end + dict(el.scalars)[pname], count=1, offset=pos)[0]
                pos += sizes[pname]
    faces, rows = [], []
    for k in sorted(polys):
        rows.append(np.array([f for f, _ in polys[k]], dtype=np.int64))
        faces.append(np.array([i for _, i in polys[k]], dtype=np.int64).reshape(-1, k))
    return (faces, rows, props, n), pos


def _offset_of_list(el: PlyElement, pos: int) -> int:
    """Byte offset of the first face's list count (scalars before the list in file order)."""
    off = pos
    for pname in el.order:
        if pname in _FACE_LISTS:
            return off
        off += np.dtype(dict(el.scalars)[pname]).itemsize
    return off


def _read_ascii(body: bytes, elements: list[PlyElement], path: Path) -> PlyMesh:
    lines = body.decode("ascii", errors="replace").splitlines()
    li = 0
    vertex: dict[str, np.ndarray] = {}
    faces, rows, props, nf = [], [], {}, 0
    try:
        for el in elements:
            chunk = lines[li:li + el.count]
            li += el.count
            if len(chunk) < el.count:
                raise PanovoccError(f"PLY is truncated in element {el.name!r}", path)
            if el.name == "face":
                nf = el.count
                props = {s: np.zeros(el.count, dtype=t) for s, t in el.scalars}
                polys: dict[int, list] = {}
                for f, line in enumerate(chunk):
                    vals = line.split()
                    p = 0
                    for pname in el.order:
                        if pname in _FACE_LISTS:
                            k = int(vals[p])
                            polys.setdefault(k, []).append((f, [int(x) for x in vals[p + 1:p + 1 + k]]))
                            p += 1 + k
                        else:
                            props[pname][f] = float(vals[p])
                            p += 1
                for k in sorted(polys):
                    rows.append(np.array([f for f, _ in polys[k]], dtype=np.int64))
                    faces.append(np.array([i for _, i in polys[k]], dtype=np.int64).reshape(-1, k))
            elif el.name == "vertex":
                arr = np.array([l.split()[:len(el.scalars)] for l in chunk], dtype=np.float64).reshape(
                    el.count, len(el.scalars))
                vertex = {n: arr[:, j].astype(t) for j, (n, t) in enumerate(el.scalars)}
    except (ValueError, IndexError):
        raise PanovoccError("malformed ASCII PLY body", path) from None
    return PlyMesh(vertex, faces, rows, props, nf)


def write_ply(path: str | Path, vertex: dict[str, np.ndarray], vertex_types: list[tuple[str, str]],
              faces: np.ndarray | None = None, face_props: dict[str, np.ndarray] | None = None,
              face_types: list[tuple[str, str]] = (), list_name: str = "vertex_indices",
              comment: str | None = None) -> None:
    """Atomically write a binary little-endian PLY (a mesh, or a point cloud when ``faces`` is None).

    Parameters
    ----------
    vertex : name -> (V,) array; written in the order of ``vertex_types`` [(name, ply type), ...]
    faces : (F, n) int, polygons of one size n (3 or 4), written as ``list uchar int``; None: no face element
    face_props : name -> (F,) array, written after the list in the order of ``face_types``
    comment : one header comment line, optional
    """
    nv = len(next(iter(vertex.values())))
    vdt = np.dtype([(n, "<" + _TYPES[t]) for n, t in vertex_types])
    varr = np.empty(nv, dtype=vdt)
    for n, _ in vertex_types:
        varr[n] = vertex[n]
    header = ["ply", "format binary_little_endian 1.0"] + ([f"comment {comment}"] if comment else [])
    header += [f"element vertex {nv}"] + [f"property {t} {n}" for n, t in vertex_types]
    farr = None
    if faces is not None:
        faces = np.asarray(faces)
        k = faces.shape[1]
        fdt = np.dtype([("n", "u1"), ("idx", "<i4", (k,))] + [(n, "<" + _TYPES[t]) for n, t in face_types])
        farr = np.empty(len(faces), dtype=fdt)
        farr["n"] = k
        farr["idx"] = faces
        for n, _ in face_types:
            farr[n] = face_props[n]
        header += [f"element face {len(faces)}", f"property list uchar int {list_name}"]
        header += [f"property {t} {n}" for n, t in face_types]
    header.append("end_header")
    with atomic_path(path, suffix=".ply") as tmp:
        with open(tmp, "wb") as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            f.write(varr.tobytes())
            if farr is not None:
                f.write(farr.tobytes())


_POINT_TYPES = [("x", "float"), ("y", "float"), ("z", "float"), ("red", "uchar"), ("green", "uchar"), ("blue", "uchar")]
POINT_CHUNK = 1 << 18
"""Points :func:`write_ply_points` converts and writes at a time."""


def write_ply_points(path: str | Path, points, colors=None, comment: str = "panovocc occupied voxel centres",
                     count: int | None = None) -> None:
    """Atomically write a binary little-endian coloured point cloud.

    points : (n, 3) float, metres, world frame (stored float32); colors : (n, 3) uint8. Or, with
    ``count``: ``points`` an iterable of ``(points, colors)`` chunks of ``count`` points in all (a large
    cloud written without its whole arrays at once); the same bytes either way.
    """
    if count is None:
        pts = np.asarray(points).reshape(-1, 3)
        col = np.asarray(colors).reshape(-1, 3)
        count = len(pts)
        chunks = ((pts[a:a + POINT_CHUNK], col[a:a + POINT_CHUNK]) for a in range(0, count, POINT_CHUNK))
    else:
        chunks = points
    vdt = np.dtype([(n, "<" + _TYPES[t]) for n, t in _POINT_TYPES])
    header = ["ply", "format binary_little_endian 1.0"] + ([f"comment {comment}"] if comment else [])
    header += [f"element vertex {count}"] + [f"property {t} {n}" for n, t in _POINT_TYPES] + ["end_header"]
    written = 0
    with atomic_path(path, suffix=".ply") as tmp:
        with open(tmp, "wb") as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            for pts, col in chunks:
                pts = np.asarray(pts, np.float32).reshape(-1, 3)
                col = np.asarray(col, np.uint8).reshape(-1, 3)
                varr = np.empty(len(pts), dtype=vdt)
                for k, name in enumerate(("x", "y", "z")):
                    varr[name] = pts[:, k]
                for k, name in enumerate(("red", "green", "blue")):
                    varr[name] = col[:, k]
                f.write(varr.tobytes())
                written += len(pts)
            if written != count:
                raise PanovoccError(f"point cloud of {count} points got {written}", path)
