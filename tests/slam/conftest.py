"""A small looped panoramic sequence for the SLAM tests (built once per session, 256 x 128, realistic noise).

``loop_seq``: one synthetic room (``synth --seed 3 --rooms 1``), a camera circling 0.6 m around the room's
middle twice (48 frames, 0.157 m and 15 degrees a frame), rendered with ``--noise realistic``: the second lap
revisits every place of the first, so loop closures can be found.
"""

from __future__ import annotations

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
