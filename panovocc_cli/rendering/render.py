"""The render stage: a scene + a trajectory -> a panoramic RGB-D sequence folder (CONVENTIONS.md).

The folder is built in a temporary folder beside the target and renamed on success, so a failed run
leaves nothing. PNGs are written by a background thread (low compression) while the next frame is cast.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..classes import canonical_name
from ..config import (DEFAULT_SEED, DEFAULT_WIDTH, DEPTH_SCALE, MAX_SEED, MIN_WIDTH, NOISE_MODELS, option,
                      validate_config)
from ..errors import PanovoccError

BACKENDS = ("raycast", "pyrender")


@dataclass
class RenderConfig:
    """Options of ``panovocc render``.

    scene: Replica-format scene folder; out: sequence folder to write; traj: trajectory (NICE-SLAM or
    TUM; default SCENE/traj.txt); width: ERP width in pixels (even, height = width / 2); backend:
    raycast | pyrender; every: keep every k-th pose; noise: none | realistic; seed: noise seed;
    threads: ray-casting threads (0 = all cores); overwrite: replace a previous sequence in ``out`` (only a
    folder holding meta.json; never one holding an input).
    """

    scene: Path = option(argument=True, metavar="SCENE",
                         help="Replica-format scene folder (habitat/mesh_semantic.ply + info_semantic.json).")
    out: Path = option(argument=True, metavar="SEQ",
                       help="Sequence folder to write (meta.json, rgb/, depth/, semantic/, poses.txt).")
    traj: Path | None = option(None, help="Trajectory, NICE-SLAM (16 numbers a line) or TUM; default SCENE/traj.txt.")
    width: int = option(DEFAULT_WIDTH, min=MIN_WIDTH, even=True, help="ERP width in pixels (even; height = width / 2).")
    backend: str = option("raycast", choices=BACKENDS, help="raycast (exact spherical rays, Open3D) or pyrender "
                          "(six rasterised cube faces, OSMesa).")
    every: int = option(1, min=1, help="Render every k-th pose.")
    noise: str = option("none", choices=NOISE_MODELS, help="none, or realistic: range-dependent depth noise (metres), "
                        "dropouts, no depth on glass, edge bleeding.")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Noise seed.")
    threads: int = option(0, min=0, help="Ray-casting threads (0 = all cores).")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous panovocc sequence in SEQ (never any other folder, "
                                         "never an input).")


def make_renderer(scene, width: int, backend: str, threads: int = 0):
    """A renderer with ``.render(T_world_cam) -> Frame`` for ``backend`` (``raycast`` or ``pyrender``)."""
    if backend == "raycast":
        from .raycast import RaycastRenderer

        return RaycastRenderer(scene, width, threads=threads)
    if backend == "pyrender":
        from .pyrender_backend import PyrenderRenderer

        return PyrenderRenderer(scene, width)
    raise PanovoccError(f"unknown backend {backend!r} (expected one of {', '.join(BACKENDS)})")


def run_render(cfg: RenderConfig) -> dict:
    """Render ``cfg.scene`` along the trajectory into ``cfg.out``; returns a summary dict."""
    from tqdm import tqdm

    from ..datasets.replica import TRAJ_NAME, read_replica_scene, scene_files, scene_paths
    from ..io.atomic import atomic_dir, check_output
    from ..io.poses import read_poses
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from ..io.images import write_png
    from ..io.sequence import SequenceMeta, frame_images, write_meta, write_sequence_poses
    from .noise import NOISE_PARAMS, degrade

    cfg = validate_config(cfg)  # width, every, seed, threads, backend, noise: the ranges declared above
    W, H = cfg.width, cfg.width // 2  # even and >= MIN_WIDTH: declared on RenderConfig.width
    scene_paths(cfg.scene)  # a missing scene is named before its trajectory
    traj = Path(cfg.traj) if cfg.traj is not None else Path(cfg.scene) / TRAJ_NAME
    check_output(cfg.out, "sequence", cfg.overwrite, inputs=(cfg.scene, traj, *scene_files(cfg.scene)))
    poses = read_poses(traj)[::cfg.every]
    scene = read_replica_scene(cfg.scene)
    glass_ids = [i for i, c in enumerate(scene.class_names) if canonical_name(c) == "window"]
    renderer = make_renderer(scene, W, cfg.backend, cfg.threads)
    meta = SequenceMeta(width=W, height=H, frames=len(poses), camera="erp", depth_scale=DEPTH_SCALE,
                        class_names=list(scene.class_names),
                        extra={"render": {"backend": cfg.backend, "noise": cfg.noise, "seed": cfg.seed,
                                          "scene": str(cfg.scene), "trajectory": str(traj), "every": cfg.every}})
    if cfg.noise == "realistic":
        meta.extra["render"]["noise_params"] = dict(NOISE_PARAMS)
    t0 = time.perf_counter()
    valid = 0.0
    # PNG encoding runs in threads (OpenCV releases the GIL). On a machine with few cores, overlapping it
    # with the next cast_rays makes both slower (Open3D's parallel loop waits for its slowest thread), so
    # there each frame's writes finish before the next frame is cast; with more cores they overlap.
    cores = os.cpu_count() or 1
    ahead = 0 if cores <= 2 else 2
    with atomic_dir(cfg.out) as tmp, ThreadPoolExecutor(max_workers=3) as pool:
        write_meta(tmp, meta)
        write_sequence_poses(tmp, poses)
        write_run_config(tmp / CONFIG_NAME, replace(cfg, traj=traj))
        for d in ("rgb", "depth", "semantic"):
            (tmp / d).mkdir()
        pending: list = []
        for i, T in enumerate(tqdm(poses, desc="render", unit="frame", file=sys.stderr, disable=not cfg.progress)):
            fr = renderer.render(T)
            depth, rgb = fr.depth, fr.rgb
            if cfg.noise == "realistic":
                inc = np.arccos(np.clip(fr.cos_incidence, 0.0, 1.0)) if cfg.backend == "raycast" else np.zeros_like(
                    depth)
                depth, rgb = degrade(depth, rgb, inc, np.isin(fr.labels, glass_ids), cfg.seed, i)
            valid += float((depth > 0).mean())
            pending.append([pool.submit(write_png, path, image)
                            for path, image in frame_images(tmp, i, rgb, depth, fr.labels, DEPTH_SCALE)])
            while len(pending) > ahead:
                for f in pending.pop(0):
                    f.result()
        for jobs in pending:
            for f in jobs:
                f.result()
    if hasattr(renderer, "close"):
        renderer.close()
    dt = time.perf_counter() - t0
    return {"frames": len(poses), "width": W, "height": H, "seconds": dt,
            "ms_per_frame": 1000.0 * dt / max(1, len(poses)), "valid_depth": valid / max(1, len(poses)),
            "classes": len(scene.class_names)}
