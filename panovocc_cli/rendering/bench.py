"""Measure the raycast render stage against bare Open3D ``cast_rays`` on the same rays.

Usage: ``python -m panovocc_cli.rendering.bench SCENE [--width 1024] [--frames 60]``

Prints ms per frame of (a) bare ``RaycastingScene.cast_rays`` on precomputed world rays of every pose and
(b) the full render stage (ray rotation, shading, labels, PNG writing of rgb/depth/semantic, meta and
poses; scene loading included) over the same poses, and their ratio. Best of ``reps`` alternating runs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ..config import DEFAULT_WIDTH


def bench(scene_dir: Path, width: int = DEFAULT_WIDTH, frames: int = 60, reps: int = 3) -> dict:
    import open3d as o3d

    from ..datasets.replica import read_replica_scene
    from ..geometry.erp import ray_directions
    from ..io.poses import read_poses, write_poses
    from .render import RenderConfig, run_render

    poses = read_poses(scene_dir / "traj.txt")[:frames]
    scene = read_replica_scene(scene_dir)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)), o3d.core.Tensor(scene.faces.astype(np.uint32)))
    cam = ray_directions(width, dtype=np.float32).reshape(-1, 3)
    rays = []
    for T in poses:
        r = np.empty((len(cam), 6), np.float32)
        r[:, :3] = T[:3, 3]
        r[:, 3:] = cam @ T[:3, :3].T.astype(np.float32)
        rays.append(o3d.core.Tensor(r))
    rs.cast_rays(rays[0])
    bare, full = np.inf, np.inf
    with tempfile.TemporaryDirectory() as tmp:
        traj = Path(tmp) / "traj.txt"
        write_poses(traj, poses)
        # Alternate the two measurements and keep the best of each: the machine may be shared.
        for rep in range(reps):
            t = time.perf_counter()
            for r in rays:
                rs.cast_rays(r)
            bare = min(bare, (time.perf_counter() - t) / len(rays))
            t = time.perf_counter()
            run_render(RenderConfig(scene=scene_dir, out=Path(tmp) / f"seq{rep}", traj=traj, width=width,
                                    progress=False))
            full = min(full, (time.perf_counter() - t) / len(poses))
    return {"bare_ms": 1000 * bare, "render_ms": 1000 * full, "ratio": full / bare, "frames": len(poses),
            "triangles": int(len(scene.faces))}


def main() -> None:
    from ..runtime import setup

    setup()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--width", type=int, default=DEFAULT_WIDTH)
    ap.add_argument("--frames", type=int, default=60)
    a = ap.parse_args()
    r = bench(a.scene, a.width, a.frames)
    print(f"{r['frames']} frames {a.width}x{a.width // 2}, {r['triangles']} triangles: bare cast_rays "
          f"{r['bare_ms']:.1f} ms/frame, render stage {r['render_ms']:.1f} ms/frame, ratio {r['ratio']:.2f}")


if __name__ == "__main__":
    main()
