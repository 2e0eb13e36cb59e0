"""``panovocc bench``: the mapper's per-frame geometric update against Open3D's C++ TSDF fusion.

Both integrate the same rendered ERP frames in one process. Open3D's ``VoxelBlockGrid`` takes each
panorama cut into 6 cube-face pinhole views (90 degrees, W/4 pixels square, z-depth, nearest-pixel
resampling; the cutting is not timed), voxel size and block size as ours (8^3), depth_max = our
max_range, truncation 3 voxels (TRUNC_VOXELS). Timed for us: PSVF kernel + free-space test + delta
extraction + memory add (``update``), in a loop of its own over the same in-memory frames (no file
reading or writing beside it), and separately the end-to-end ``run_map`` (frames read, deltas written
by a background thread that competes for the cores, so its ``update`` share reads higher).

Statistic: each pass integrates every frame into a fresh map; its figure is total time / frames. Both
sides get one untimed warm-up, then ``repeats`` timed passes, ours and Open3D's interleaved so that
load from other jobs hits both alike; the figures are the medians over the passes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..io.atomic import write_text
from ..io.sequence import Sequence, read_meta

TRUNC_VOXELS = 3.0  # Open3D TSDF truncation, voxels (its default is 8; 3 is the usual TSDF setting)


@dataclass
class BenchConfig:
    out: str  # working folder
    frames: int = 20
    width: int = 1024  # ERP width, pixels
    voxel_size: float = 0.08  # metres
    seed: int = 0
    repeats: int = 5  # timed passes of each side (median reported)


def cube_faces(depth: np.ndarray, face: int):
    """Cut a radial ERP depth map into 6 pinhole z-depth faces.

    Returns
    -------
    list of (R_cam_face (3, 3) float64, depth_z (face, face) float32 metres)
    K : (3, 3) float64 intrinsics of every face (90 degree field of view)
    """
    H, W = depth.shape
    f = face / 2.0
    K = np.array([[f, 0, face / 2 - 0.5], [0, f, face / 2 - 0.5], [0, 0, 1.0]])
    u, v = np.meshgrid(np.arange(face), np.arange(face))
    dirs = np.stack([(u - K[0, 2]) / f, (v - K[1, 2]) / f, np.ones((face, face))], -1)

    def rot_y(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rot_x(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    out = []
    for R in (rot_y(0), rot_y(np.pi / 2), rot_y(np.pi), rot_y(-np.pi / 2), rot_x(np.pi / 2), rot_x(-np.pi / 2)):
        d = dirs @ R.T
        n = np.linalg.norm(d, axis=-1)
        theta = np.arctan2(d[..., 0], d[..., 2])
        phi = -np.arcsin(d[..., 1] / n)
        col = np.floor((theta + np.pi) * W / (2 * np.pi)).astype(np.int64) % W
        row = np.clip(np.floor((np.pi / 2 - phi) * H / np.pi).astype(np.int64), 0, H - 1)
        out.append((R, (depth[row, col] / n).astype(np.float32)))
    return out, K


def open3d_tsdf_pass(depths, poses, voxel_size: float, depth_max: float):
    """A callable that integrates every frame into a fresh Open3D VoxelBlockGrid TSDF (6 cube faces per
    panorama, CPU) and returns ms per panorama. The faces are cut here, once, untimed; one warm-up pass
    (the first 6 faces) runs before returning."""
    import open3d as o3d
    import open3d.core as o3c

    dev = o3c.Device("CPU:0")
    face = depths[0].shape[1] // 4
    prepared = []
    for d, T in zip(depths, poses):
        faces, K = cube_faces(d, face)
        for R, z in faces:
            T_face = np.eye(4)
            T_face[:3, :3] = T[:3, :3] @ R
            T_face[:3, 3] = T[:3, 3]
            prepared.append((o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(z))),
                             o3c.Tensor(np.linalg.inv(T_face), o3c.float64)))
    Kt = o3c.Tensor(K, o3c.float64)

    def run(items):
        vbg = o3d.t.geometry.VoxelBlockGrid(attr_names=("tsdf", "weight"), attr_dtypes=(o3c.float32, o3c.float32),
                                            attr_channels=((1), (1)), voxel_size=voxel_size, block_resolution=8,
                                            block_count=100000, device=dev)
        t0 = time.perf_counter()
        for img, ext in items:
            blocks = vbg.compute_unique_block_coordinates(img, Kt, ext, 1.0, depth_max, TRUNC_VOXELS)
            vbg.integrate(blocks, img, Kt, ext, 1.0, depth_max, TRUNC_VOXELS)
        return time.perf_counter() - t0

    run(prepared[:6])  # warm-up
    return lambda: 1e3 * run(prepared) / len(depths)


def open3d_tsdf_ms(depths, poses, voxel_size: float, depth_max: float) -> float:
    """ms per panorama of one Open3D TSDF pass (see :func:`open3d_tsdf_pass`)."""
    return open3d_tsdf_pass(depths, poses, voxel_size, depth_max)()


def panovocc_update_pass(depths, poses, geo):
    """A callable that runs the geometric update (:func:`~.contributors.geometry_delta` then
    :meth:`~.memory.VoxelMemory.add`) of every frame into a fresh memory and returns ms per frame.
    One warm-up pass (numba compilation / cache load) runs before returning.

    depths : list of (H, W) float32, metres, radial; poses : (N, 4, 4) float64 T_world_cam
    geo : :class:`~.params.GeometryParams` (stride resolved)
    """
    from .contributors import geometry_delta
    from .memory import GEOMETRY_CHANNELS, VoxelMemory

    def run():
        mem = VoxelMemory(geo.voxel_size, GEOMETRY_CHANNELS)
        t0 = time.perf_counter()
        for d, T in zip(depths, poses):
            mem.add(geometry_delta(d, T, geo))
        return 1e3 * (time.perf_counter() - t0) / len(depths)

    run()
    return run


def run_bench(cfg: BenchConfig) -> dict:
    """Render (once) a furnished-room sequence, map it, fuse it with Open3D; return and save the figures."""
    from .pipeline import MapConfig, resolve, run_map
    from .params import GeometryParams
    from .synthetic import write_room_sequence

    if cfg.frames < 2 or cfg.width < 64 or cfg.repeats < 1:
        raise PanovoccError("bench needs at least 2 frames, width >= 64 and repeats >= 1")
    out = Path(cfg.out)
    seq_dir = out / f"seq_{cfg.width}x{cfg.width // 2}_{cfg.frames}"
    try:
        meta = read_meta(seq_dir)
        fresh = meta.frames != cfg.frames or meta.width != cfg.width
    except PanovoccError:
        fresh = True
    if fresh:
        write_room_sequence(seq_dir, cfg.frames, cfg.width, seed=cfg.seed)
    seq = Sequence(seq_dir)
    depths = [seq.depth(i) for i in range(len(seq))]
    geo = GeometryParams(voxel_size=cfg.voxel_size)
    mcfg = MapConfig(seq=str(seq_dir), out=str(out / "map"), geometry=geo, checkpoint_every=0)
    geo = resolve(mcfg, cfg.width).geometry
    ours_pass = panovocc_update_pass(depths, seq.poses, geo)  # also compiles / loads the numba cache
    s = run_map(mcfg, overwrite=True, progress=False)
    o3d_pass = open3d_tsdf_pass(depths, seq.poses, cfg.voxel_size, geo.max_range)
    ours, o3d = [], []
    for _ in range(cfg.repeats):  # interleaved, so that other jobs' load hits both sides alike
        ours.append(ours_pass())
        o3d.append(o3d_pass())
    ours_ms, o3d_ms = float(np.median(ours)), float(np.median(o3d))
    ratio = ours_ms / o3d_ms
    res = {"config": asdict(cfg), "stride": geo.stride,
           "statistic": f"median over {cfg.repeats} interleaved passes of (pass time / frames)",
           "panovocc_update_ms_per_frame": ours_ms, "panovocc_update_passes_ms": ours,
           "panovocc_end_to_end_ms_per_frame": s["ms_per_frame"],
           "panovocc_update_in_run_map_ms_per_frame": s["update_ms_per_frame"],
           "open3d_tsdf_ms_per_frame": o3d_ms, "open3d_tsdf_passes_ms": o3d, "ratio": ratio}
    res["line"] = (f"{cfg.frames} frames {cfg.width}x{cfg.width // 2}: panovocc geometric update "
                   f"{ours_ms:.1f} ms/frame (map end to end with delta writes {s['ms_per_frame']:.1f}), "
                   f"Open3D VoxelBlockGrid TSDF (6 cube faces) {o3d_ms:.1f} ms/frame, ratio {ratio:.2f}x "
                   f"(medians of {cfg.repeats} passes)")
    write_text(out / "bench.json", json.dumps(res, indent=2) + "\n")
    return res
