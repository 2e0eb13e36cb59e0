"""Small looped panoramic sequences for the SLAM tests (built once per session, 256 x 128, realistic noise).

``loop_seq``: one synthetic room (``synth --seed 3 --rooms 1``), a camera circling 0.6 m around the room's
middle twice (48 frames, 0.157 m and 15 degrees a frame), rendered with ``--noise realistic``: the second lap
revisits every place of the first, so loop closures can be found. ``short_seq``: its first N_SHORT frames.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="session")
def loop_seq(tmp_path_factory) -> Path:
    from panovocc_cli.datasets.synth import SynthConfig, run_synth
    from panovocc_cli.geometry.poses import look_at
    from panovocc_cli.io.poses import read_poses, write_poses
    from panovocc_cli.rendering.render import RenderConfig, run_render

    root = tmp_path_factory.mktemp("slam")
    run_synth(SynthConfig(out=root / "scene", seed=3, rooms=1, frames=40))
    c = read_poses(root / "scene" / "traj.txt")[:, :3, 3].mean(0)
    a = np.linspace(0, 4 * np.pi, 48, endpoint=False)
    write_poses(root / "loop.txt", np.stack([look_at(c + [0.6 * np.cos(t), 0.6 * np.sin(t), 0.0],
                                                     [-np.sin(t), np.cos(t), 0.0]) for t in a]))
    run_render(RenderConfig(scene=root / "scene", out=root / "seq", traj=root / "loop.txt", width=256,
                            noise="realistic", seed=0, threads=1, progress=False))
    return root / "seq"


N_SHORT = 12  # frames of the short sequence: half a lap of loop_seq (0.157 m and 15 degrees a frame)


@pytest.fixture(scope="module")
def short_seq(loop_seq, tmp_path_factory):
    """The first N_SHORT frames of ``loop_seq`` (its true poses in poses.txt)."""
    from panovocc_cli.io.poses import read_poses, write_poses

    root = tmp_path_factory.mktemp("first_pose") / "seq"
    for sub in ("rgb", "depth", "semantic"):
        (root / sub).mkdir(parents=True)
        for f in sorted((loop_seq / sub).iterdir())[:N_SHORT]:
            shutil.copyfile(f, root / sub / f.name)
    meta = json.loads((loop_seq / "meta.json").read_text())
    (root / "meta.json").write_text(json.dumps(meta | {"frames": N_SHORT}))
    write_poses(root / "poses.txt", read_poses(loop_seq / "poses.txt")[:N_SHORT])
    return root
