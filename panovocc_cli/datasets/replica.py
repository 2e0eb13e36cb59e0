"""Replica scenes: ``habitat/mesh_semantic.ply`` + ``habitat/info_semantic.json``.

``mesh_semantic.ply`` is binary little-endian with vertex ``x y z`` (float), ``nx ny nz`` (float),
``red green blue`` (uchar), and faces ``list uchar int vertex_indices`` (quads) plus ``int object_id``.
``info_semantic.json`` holds ``classes`` ([{id, name}]), ``objects`` ([{id, class_id, class_name, ...}])
and ``id_to_label`` (object id -> class id). Class names are mapped to canonical ones here, once
(``tv-screen`` -> ``tv``, ``lamp`` -> ``lighting``; see :mod:`panovocc_cli.classes`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from ..classes import UNLABELED, canonical_name
from ..errors import PanovoccError
from ..io.atomic import write_text
from ..io.jsonfile import read_json
from ..io.ply import read_ply, write_ply
from .scene import Scene, split_polygons

MESH_PATH = Path("habitat") / "mesh_semantic.ply"
INFO_PATH = Path("habitat") / "info_semantic.json"
TRAJ_NAME = "traj.txt"
_NO_CLASS = {"", "undefined", "unlabeled", "unlabelled", "void", "none", "background"}


def scene_paths(scene: str | Path) -> tuple[Path, Path]:
    """``(mesh_semantic.ply, info_semantic.json)`` of a scene folder (or of a PLY path given directly)."""
    p = Path(scene)
    if p.suffix.lower() == ".ply":
        return p, p.with_name("info_semantic.json")
    if not p.is_dir():
        raise PanovoccError("scene folder not found (expected a Replica folder with habitat/mesh_semantic.ply)", p)
    return p / MESH_PATH, p / INFO_PATH


def scene_files(scene: str | Path) -> tuple[Path, ...]:
    """The files a scene's reader opens (for the output guard: never write over them); () when ``scene``
    is not a scene folder."""
    try:
        return scene_paths(scene)
    except PanovoccError:
        return ()


def _load_info(path: Path) -> tuple[dict[int, str], dict[int, str]]:
    """Class names by class id and class names by object id (raw, not canonical)."""
    info = read_json(path, "Replica's info_semantic.json")
    if not isinstance(info, dict) or not isinstance(info.get("classes"), list):
        raise PanovoccError("expected a JSON object with a 'classes' list of {id, name}", path)
    try:
        classes = {int(c["id"]): str(c["name"]) for c in info["classes"]}
        if len(classes) != len(info["classes"]):
            raise PanovoccError("'classes' lists the same id twice", path)
        raw = [str(c["name"]) for c in info["classes"]]
        dup = sorted({n for n in raw if raw.count(n) > 1})
        if dup:
            raise PanovoccError(f"'classes' has duplicate names {dup}; each class id needs its own name", path)
        obj_class: dict[int, str] = {}
        for o in info.get("objects", []) or []:
            name = o.get("class_name")
            if name is None and "class_id" in o:
                name = classes.get(int(o["class_id"]))
            if name is not None:
                obj_class[int(o["id"])] = str(name)
        for oid, cid in enumerate(info.get("id_to_label", []) or []):
            cid = int(cid)
            if cid in classes:
                obj_class[oid] = classes[cid]
            elif cid < 0 or oid not in obj_class:
                obj_class[oid] = UNLABELED
    except (KeyError, TypeError, ValueError) as e:
        raise PanovoccError(f"malformed classes/objects/id_to_label ({type(e).__name__}: {e})", path) from None
    return classes, obj_class


def read_replica_scene(folder: str | Path) -> Scene:
    """Read a Replica scene folder into a :class:`Scene` (quads split into triangles).

    Parameters
    ----------
    folder : a folder with ``habitat/mesh_semantic.ply`` and ``habitat/info_semantic.json``
        (or the PLY's path, with ``info_semantic.json`` beside it)

    Returns
    -------
    Scene with canonical class names: ``[unlabeled] + `` the file's classes in class-id order
    (duplicates after canonical mapping merged).
    """
    ply_path, info_path = scene_paths(folder)
    classes, obj_class = _load_info(info_path)
    mesh = read_ply(ply_path)
    for k in ("x", "y", "z"):
        if k not in mesh.vertex:
            raise PanovoccError(f"PLY vertices lack '{k}'", ply_path)
    if "object_id" not in mesh.face:
        raise PanovoccError("PLY faces lack 'object_id' (expected Replica's mesh_semantic.ply with per-face "
                            "object ids)", ply_path)
    if mesh.num_faces == 0:
        raise PanovoccError("PLY has no faces", ply_path)
    v = np.stack([mesh.vertex[k] for k in ("x", "y", "z")], axis=1).astype(np.float64)
    if all(k in mesh.vertex for k in ("red", "green", "blue")):
        col = np.stack([mesh.vertex[k] for k in ("red", "green", "blue")], axis=1)
        if col.dtype.kind == "f":
            col = np.clip(np.round(col * (255.0 if col.max() <= 1.0 else 1.0)), 0, 255)
        col = col.astype(np.uint8)
    else:
        col = np.full((len(v), 3), 180, np.uint8)

    names = [UNLABELED]
    index = {UNLABELED: 0}

    def cid(raw: str) -> int:
        c = canonical_name(raw)
        if c in _NO_CLASS:
            return 0
        if c not in index:
            index[c] = len(names)
            names.append(c)
        return index[c]

    for k in sorted(classes):
        cid(classes[k])
    obj_ids = np.asarray(mesh.face["object_id"]).astype(np.int64)
    if obj_class and len(obj_ids) and obj_ids.max() > max(obj_class):
        raise PanovoccError(f"face object_id {int(obj_ids.max())} is beyond the objects of {info_path.name} "
                            f"(largest id {max(obj_class)})", ply_path)
    uniq = np.unique(obj_ids)
    lut_c = np.array([cid(obj_class.get(int(o), UNLABELED)) for o in uniq], dtype=np.int32)

    tris, fobj = [], []
    for poly, rows in zip(mesh.faces, mesh.face_rows):
        if poly.shape[1] < 3:
            raise PanovoccError(f"PLY has faces with {poly.shape[1]} vertices", ply_path)
        tris.append(split_polygons(poly))
        fobj.append(np.repeat(obj_ids[rows], poly.shape[1] - 2))
    faces = np.concatenate(tris)
    face_object = np.concatenate(fobj)
    if faces.min() < 0 or faces.max() >= len(v):
        raise PanovoccError(f"PLY face index out of range ({len(v)} vertices)", ply_path)
    face_class = lut_c[np.searchsorted(uniq, face_object)]
    name = Path(folder).name if Path(folder).suffix.lower() != ".ply" else Path(folder).parent.parent.name
    return Scene(v, faces, face_class, face_object.astype(np.int32), col, names, name=name).validate()


def vertex_normals(vertices: np.ndarray, polygons: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) float32 of polygons (F, n) (zero for unused vertices)."""
    tris = split_polygons(polygons)
    p = vertices[tris]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    vn = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    n = np.linalg.norm(vn, axis=1, keepdims=True)
    return (vn / np.where(n > 0, n, 1.0)).astype(np.float32)


def write_replica_scene(folder: str | Path, vertices: np.ndarray, polygons: np.ndarray, face_object: np.ndarray,
                        vertex_colors: np.ndarray, object_classes: Sequence[str],
                        normals: np.ndarray | None = None) -> None:
    """Write ``folder/habitat/mesh_semantic.ply`` and ``info_semantic.json`` in Replica's format.

    Parameters
    ----------
    vertices : (V, 3) float, metres, world frame (+Z up); stored as float32 like Replica
    polygons : (F, n) int, n = 4 (Replica's quads) or 3
    face_object : (F,) int object id of each face, ids into ``object_classes``
    vertex_colors : (V, 3) uint8 RGB
    object_classes : Replica class name of each object id (e.g. ``"tv-screen"``, ``"lamp"``)
    normals : (V, 3) float, optional; area-weighted vertex normals when omitted
    """
    folder = Path(folder)
    vertices = np.asarray(vertices, dtype=np.float64)
    if normals is None:
        normals = vertex_normals(vertices, polygons)
    vertex = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2],
              "nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2],
              "red": vertex_colors[:, 0], "green": vertex_colors[:, 1], "blue": vertex_colors[:, 2]}
    vtypes = [(k, "float") for k in ("x", "y", "z", "nx", "ny", "nz")] + [(k, "uchar") for k in ("red", "green", "blue")]
    write_ply(folder / MESH_PATH, vertex, vtypes, np.asarray(polygons, dtype=np.int32),
              {"object_id": np.asarray(face_object, dtype=np.int32)}, [("object_id", "int")])
    class_list: list[str] = []
    for c in object_classes:
        if c not in class_list:
            class_list.append(c)
    class_id = {c: i + 1 for i, c in enumerate(class_list)}  # Replica's class ids start at 1
    info = {
        "classes": [{"id": class_id[c], "name": c} for c in class_list],
        "objects": [{"id": i, "class_id": class_id[c], "class_name": c} for i, c in enumerate(object_classes)],
        "id_to_label": [class_id[c] for c in object_classes],
    }
    write_text(folder / INFO_PATH, json.dumps(info, indent=1) + "\n")
