"""A labelled triangle mesh of an indoor scene: the common form of Replica scenes and synthetic ones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..classes import UNLABELED
from ..errors import PanovoccError


@dataclass
class Scene:
    """A labelled indoor mesh, world frame (metres, +Z up).

    Attributes
    ----------
    vertices : (V, 3) float64, metres, world frame
    faces : (F, 3) int32 triangle vertex indices (quads are split into two triangles)
    face_class : (F,) int32 ids into ``class_names`` (0 = unlabeled)
    face_object : (F,) int32 object (instance) id of each face
    vertex_colors : (V, 3) uint8 RGB
    class_names : list[str] canonical class names, ``class_names[0] == "unlabeled"``
    name : str, a label for messages and meta.json
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_class: np.ndarray
    face_object: np.ndarray
    vertex_colors: np.ndarray
    class_names: list[str]
    name: str = "scene"

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        self.face_class = np.ascontiguousarray(self.face_class, dtype=np.int32)
        self.face_object = np.ascontiguousarray(self.face_object, dtype=np.int32)
        self.vertex_colors = np.ascontiguousarray(self.vertex_colors, dtype=np.uint8)
        self.class_names = [str(c) for c in self.class_names]

    def validate(self) -> "Scene":
        """Check shapes, index ranges and ``class_names[0]``; raises :class:`PanovoccError`."""
        v, f = self.vertices, self.faces
        if v.ndim != 2 or v.shape[1] != 3 or not len(v):
            raise PanovoccError(f"scene {self.name}: vertices must be (V, 3) with V > 0, got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or not len(f):
            raise PanovoccError(f"scene {self.name}: faces must be (F, 3) with F > 0, got {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise PanovoccError(f"scene {self.name}: face vertex index out of range (V = {len(v)})")
        if self.face_class.shape != (len(f),) or self.face_object.shape != (len(f),):
            raise PanovoccError(f"scene {self.name}: face_class/face_object must have one entry per face")
        if self.vertex_colors.shape != v.shape:
            raise PanovoccError(f"scene {self.name}: vertex_colors must be (V, 3)")
        if not self.class_names or self.class_names[0] != UNLABELED:
            raise PanovoccError(f"scene {self.name}: class_names[0] must be '{UNLABELED}'")
        if self.face_class.min() < 0 or self.face_class.max() >= len(self.class_names):
            raise PanovoccError(f"scene {self.name}: face class id out of range ({len(self.class_names)} classes)")
        if not np.all(np.isfinite(v)):
            raise PanovoccError(f"scene {self.name}: vertices contain NaN or infinite values")
        return self

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds ``(lo, hi)``, each (3,) float64 metres."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def triangle_areas(self) -> np.ndarray:
        """Area (F,) float64 m^2 of each triangle."""
        p = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    def class_ids_present(self) -> np.ndarray:
        """Sorted class ids that at least one face carries."""
        return np.unique(self.face_class)


def split_polygons(polys: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons ``(F, n)`` int into triangles ``(F (n - 2), 3)``.

    Triangles of one polygon are consecutive: polygon f gives rows ``f (n-2) ... f (n-2) + n - 3``.
    A quad ``(a, b, c, d)`` gives ``(a, b, c)`` and ``(a, c, d)``; the winding (normal) is kept.
    """
    polys = np.asarray(polys)
    n = polys.shape[1]
    if n < 3:
        raise PanovoccError(f"faces with {n} vertices cannot be triangulated")
    tris = [np.stack([polys[:, 0], polys[:, k], polys[:, k + 1]], axis=1) for k in range(1, n - 1)]
    return np.stack(tris, axis=1).reshape(-1, 3)
