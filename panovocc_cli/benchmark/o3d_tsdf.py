"""The Open3D side of ``panovocc bench``'s whole-process comparison: ``python -m panovocc_cli.benchmark.o3d_tsdf
SEQ OUT [--voxel-size H] [--depth-max M]``.

What a user of Open3D's ``VoxelBlockGrid`` TSDF fusion runs on a panoramic sequence: read each frame's
depth file and pose, cut the panorama into 6 cube-face pinhole views (:func:`.bench.cube_faces`), integrate
them (CPU, block resolution 8, truncation :data:`panovocc_cli.baselines.tsdf.TRUNC_VOXELS` voxels), extract the surface point
cloud and write it to ``OUT/o3d_tsdf.ply``. Timed as a whole process by :func:`.bench.run_bench`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..config import DEFAULT_VOXEL_SIZE


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m panovocc_cli.benchmark.o3d_tsdf", description=__doc__.splitlines()[0])
    ap.add_argument("seq")
    ap.add_argument("out")
    ap.add_argument("--voxel-size", type=float, default=DEFAULT_VOXEL_SIZE)
    ap.add_argument("--depth-max", type=float, default=10.0)
    a = ap.parse_args(argv)

    import open3d as o3d
    import open3d.core as o3c

    from ..baselines.tsdf import TRUNC_VOXELS
    from ..io.sequence import Sequence
    from .bench import cube_faces, cube_sampler

    seq = Sequence(a.seq)
    sampler = cube_sampler(seq.meta.width)
    Kt = o3c.Tensor(sampler.rig[0].camera.K, o3c.float64)
    # a colour attribute, left at zero (depth-only integration): this Open3D's extract_point_cloud fails without one
    vbg = o3d.t.geometry.VoxelBlockGrid(attr_names=("tsdf", "weight", "color"),
                                        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32), attr_channels=((1), (1), (3)), voxel_size=a.voxel_size, block_resolution=8,
                                        block_count=100000, device=o3c.Device("CPU:0"))
    for i in range(len(seq)):
        T = seq.poses[i]
        faces, _ = cube_faces(seq.depth(i), sampler)
        for R, z in faces:
            T_face = np.eye(4)
            T_face[:3, :3] = T[:3, :3] @ R
            T_face[:3, 3] = T[:3, 3]
            img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(z)))
            ext = o3c.Tensor(np.linalg.inv(T_face), o3c.float64)
            blocks = vbg.compute_unique_block_coordinates(img, Kt, ext, 1.0, a.depth_max, TRUNC_VOXELS)
            vbg.integrate(blocks, img, Kt, ext, 1.0, a.depth_max, TRUNC_VOXELS)
    pcd = vbg.extract_point_cloud()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    o3d.t.io.write_point_cloud(str(out / "o3d_tsdf.ply"), pcd)
    print(f"{len(seq)} frames -> {pcd.point.positions.shape[0]} points in {out / 'o3d_tsdf.ply'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
