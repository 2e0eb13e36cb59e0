"""Analytic test scenes for the mapper: a furnished box room, ERP depth by exact ray casting.

Used by ``panovocc bench`` and by the mapping tests (answers known in closed form: walls at known
planes). World frame +Z up; ERP frames follow CONVENTIONS.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.erp import ray_directions
from ..geometry.poses import look_at
from ..io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses

# Surfaces deliberately off the 0.08 m lattice's planes (a floor exactly on a voxel boundary is a
# degenerate case: see docs/mapping.md, "known limits").
ROOM = ((-3.01, -2.53, 0.013), (3.03, 2.49, 2.83))  # min, max corners, metres
FURNITURE = (((1.0, 0.8, 0.013), (2.2, 2.0, 0.75)),  # table-like block
             ((-2.6, -2.2, 0.013), (-1.6, -0.6, 1.6)),  # cabinet
             ((-0.4, 1.6, 0.3), (0.4, 2.4, 1.1)))  # floating box (a shelf)


def room_mesh(furniture: bool = True):
    """Open3D legacy TriangleMesh of the room's walls (normals inward) and furniture boxes."""
    import open3d as o3d

    lo, hi = np.array(ROOM[0]), np.array(ROOM[1])
    mesh = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    mesh.translate(lo)
    if furniture:
        for a, b in FURNITURE:
            a, b = np.array(a), np.array(b)
            box = o3d.geometry.TriangleMesh.create_box(*(b - a))
            box.translate(a)
            mesh += box
    return mesh


class ErpRenderer:
    """Exact radial depth of ERP frames by ray casting a mesh (Open3D RaycastingScene)."""

    def __init__(self, mesh, width: int):
        import open3d as o3d

        self._o3c = o3d.core
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        self.rays = ray_directions(width).astype(np.float64)

    def depth(self, T_world_cam: np.ndarray) -> np.ndarray:
        """(H, W) float32 radial depth, metres; 0 where no surface is hit."""
        d = self.rays @ T_world_cam[:3, :3].T
        o = np.broadcast_to(T_world_cam[:3, 3], d.shape)
        r = self.scene.cast_rays(self._o3c.Tensor(np.concatenate([o, d], -1).astype(np.float32)))
        t = r["t_hit"].numpy()
        return np.where(np.isfinite(t), t, 0.0).astype(np.float32)


def room_trajectory(n: int) -> np.ndarray:
    """(n, 4, 4) float64 T_world_cam: a loop around the room's centre at 1.2-1.6 m height, turning."""
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / max(n, 1)
        pos = np.array([1.2 * np.cos(a), 0.9 * np.sin(a), 1.4 + 0.2 * np.sin(2 * a)])
        fwd = np.array([np.cos(a + 1.0), np.sin(a + 1.0), 0.05])
        poses.append(look_at(pos, fwd, np.array([0.0, 0.0, 1.0])))
    return np.stack(poses)


def write_room_sequence(seq: str | Path, n_frames: int, width: int, noise_std: float = 0.0, seed: int = 0,
                        furniture: bool = True) -> np.ndarray:
    """Render the room along :func:`room_trajectory` into a sequence folder; return the poses.

    noise_std : float, metres; Gaussian noise added to valid radial depths (``noise_std * r / 3``
        per metre of range, so 3 m carries noise_std), for noisy-depth tests.
    """
    rng = np.random.default_rng(seed)
    ren = ErpRenderer(room_mesh(furniture), width)
    poses = room_trajectory(n_frames)
    H = width // 2
    seq = Path(seq)
    for i, T in enumerate(poses):
        d = ren.depth(T)
        if noise_std > 0:
            valid = d > 0
            d = np.where(valid, d + rng.normal(0.0, 1.0, d.shape) * noise_std * d / 3.0, 0.0).astype(np.float32)
            d = np.maximum(d, 0)
        g = np.clip(255 * (1.0 - d / 8.0), 0, 255).astype(np.uint8)
        write_frame(seq, i, np.repeat(g[..., None], 3, axis=-1), d, None)
    write_meta(seq, SequenceMeta(width=width, height=H, frames=n_frames))
    write_sequence_poses(seq, poses)
    return poses


def room_ground_truth(voxel_size: float = 0.08, samples_per_m2: float = 4000.0, seed: int = 0):
    """Ground-truth grid of the room: voxels the surfaces pass through are occupied (class ``wall``),
    other voxels whose centres are inside the room and outside the furniture are free (0), the rest
    unknown (255). Surfaces are sampled densely (``samples_per_m2`` points a square metre)."""
    from ..geometry.lattice import bounds_to_grid, point_to_index
    from ..grid import Grid

    mesh = room_mesh(True)
    area = mesh.get_surface_area()
    pcd = mesh.sample_points_uniformly(int(area * samples_per_m2), seed=seed) if _o3d_has_seed() else \
        mesh.sample_points_uniformly(int(area * samples_per_m2))
    pts = np.asarray(pcd.points)
    lo, hi = np.array(ROOM[0]) - voxel_size, np.array(ROOM[1]) + voxel_size
    i0, shape, origin = bounds_to_grid(lo, hi, voxel_size)
    labels = np.full(tuple(shape), 255, np.uint8)
    c = origin + np.argwhere(np.ones(tuple(shape), bool)) * voxel_size
    inside = np.all((c > ROOM[0]) & (c < ROOM[1]), axis=1)
    for a, b in FURNITURE:
        inside &= ~np.all((c > a) & (c < b), axis=1)
    labels.reshape(-1)[inside] = 0
    ijk = point_to_index(pts, voxel_size) - i0
    labels[tuple(ijk.T)] = 1
    return Grid(labels, origin, voxel_size, ["empty", "wall"])


def _o3d_has_seed() -> bool:
    import inspect

    import open3d as o3d

    try:
        return "seed" in inspect.signature(o3d.geometry.TriangleMesh.sample_points_uniformly).parameters
    except (TypeError, ValueError):
        return False
