"""Rasterised ERP rendering with pyrender (OSMesa, no display): six 90-degree cube faces resampled to ERP.

Each cube face is rendered twice: once lit (RGB and z-depth), once flat with each triangle's class id
encoded in its vertex colours (R = id & 255, G = id >> 8), so labels come out exact. ERP pixels take
the nearest cube-face pixel (no blending of labels or depths); z-depth becomes radial depth by dividing
by the cosine between the ERP ray and the face's optical axis. Faces are drawn double-sided like the
ray caster's, so both backends see the same surfaces.
"""

from __future__ import annotations

import os

import numpy as np

from ..datasets.scene import Scene
from ..geometry.cameras import ViewRig
from ..geometry.erp import check_erp_size, ray_directions
from ..geometry.poses import check_rigid
from .raycast import Frame

# Cube faces: columns (x_f, y_f, z_f) of each face camera (OpenCV axes) in the ERP camera frame, from the
# camera layer's cube rig: front +z, right +x, back -z, left -x, up -y, down +y (entries exactly 0 / +-1).
_FACES = np.stack([view.R_cam_view for view in ViewRig.cube(1)])
_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


class PyrenderRenderer:
    """ERP renderer by cube-map rasterisation; same outputs as :class:`RaycastRenderer`.

    Parameters
    ----------
    scene : Scene
    width : ERP width (even)
    face_size : cube-face resolution in pixels (default W / 2: at least the ERP's angular resolution)
    """

    def __init__(self, scene: Scene, width: int, face_size: int | None = None):
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
        import pyrender

        self._pr = pyrender
        self.width, self.height = check_erp_size(width)
        self.S = int(face_size or max(64, self.width // 2))
        tri = scene.vertices[scene.faces].reshape(-1, 3).astype(np.float32)
        cls = np.repeat(scene.face_class, 3)
        lab_col = np.stack([cls & 255, (cls >> 8) & 255, np.zeros_like(cls), np.full_like(cls, 255)], 1)
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0,
                                                 roughnessFactor=1.0, doubleSided=True)
        col = np.concatenate([scene.vertex_colors[scene.faces].reshape(-1, 3),
                              np.full((len(tri), 1), 255, np.uint8)], 1).astype(np.float32) / 255.0
        normals = np.repeat(np.cross(tri[1::3] - tri[0::3], tri[2::3] - tri[0::3]), 3, axis=0)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        rgb_mesh = pyrender.Mesh([pyrender.Primitive(positions=tri, normals=normals, color_0=col, mode=4,
                                                     material=mat)])
        lab_mesh = pyrender.Mesh([pyrender.Primitive(positions=tri, color_0=lab_col.astype(np.float32) / 255.0,
                                                     mode=4, material=mat)])
        cam = pyrender.PerspectiveCamera(yfov=np.pi / 2, aspectRatio=1.0, znear=0.02, zfar=100.0)
        self.rgb_scene = pyrender.Scene(ambient_light=[0.45, 0.45, 0.45], bg_color=[0, 0, 0, 0])
        self.rgb_scene.add(rgb_mesh)
        self.cam_rgb = self.rgb_scene.add(cam)
        self.light = self.rgb_scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.0))
        self.lab_scene = pyrender.Scene(ambient_light=[1.0, 1.0, 1.0], bg_color=[0, 0, 0, 0])
        self.lab_scene.add(lab_mesh)
        self.cam_lab = self.lab_scene.add(cam)
        self.renderer = pyrender.OffscreenRenderer(self.S, self.S)
        # ERP pixel -> (face, row, col) and the cosine to that face's axis, fixed for all poses.
        rays = ray_directions(self.width, self.height).reshape(-1, 3)
        local = np.einsum("fij,ni->nfj", _FACES, rays)  # (N, 6, 3): ray in each face's frame
        self.face = np.argmax(local[..., 2], axis=1)
        p = local[np.arange(len(rays)), self.face]
        self.cos = p[:, 2]
        S = self.S
        self.col = np.clip(np.floor((p[:, 0] / p[:, 2] + 1.0) * S / 2), 0, S - 1).astype(np.int64)
        self.row = np.clip(np.floor((p[:, 1] / p[:, 2] + 1.0) * S / 2), 0, S - 1).astype(np.int64)

    def render(self, T_world_cam: np.ndarray) -> Frame:
        """Render one pose (``T_world_cam`` (4, 4) float64, OpenCV axes) into a :class:`Frame`."""
        pr = self._pr
        T = check_rigid(T_world_cam, "T_world_cam")
        S = self.S
        rgb_faces = np.empty((6, S, S, 3), np.uint8)
        z_faces = np.empty((6, S, S), np.float32)
        lab_faces = np.empty((6, S, S), np.int32)
        for f in range(6):
            R = np.eye(4)
            R[:3, :3] = _FACES[f]
            pose = T @ R @ _GL_FROM_CV
            self.rgb_scene.set_pose(self.cam_rgb, pose)
            self.rgb_scene.set_pose(self.light, pose)
            c, z = self.renderer.render(self.rgb_scene, flags=pr.RenderFlags.SKIP_CULL_FACES)
            rgb_faces[f], z_faces[f] = c[..., :3], z
            self.lab_scene.set_pose(self.cam_lab, pose)
            lc, _ = self.renderer.render(self.lab_scene, flags=pr.RenderFlags.FLAT | pr.RenderFlags.SKIP_CULL_FACES)
            lab_faces[f] = lc[..., 0].astype(np.int32) | (lc[..., 1].astype(np.int32) << 8)
        idx = (self.face, self.row, self.col)
        z = z_faces[idx]
        depth = np.where(z > 0, z / self.cos, 0.0).astype(np.float32)
        labels = np.where(z > 0, lab_faces[idx], 0).astype(np.int32)
        rgb = np.where((z > 0)[:, None], rgb_faces[idx], 0).astype(np.uint8)
        H, W = self.height, self.width
        return Frame(rgb.reshape(H, W, 3), depth.reshape(H, W), labels.reshape(H, W),
                     np.zeros((H, W), np.float32))

    def close(self) -> None:
        self.renderer.delete()
