"""Floor plans of a scene with its walk (docs/scenes.md, "Buildings"): one top view per floor, from the scene's
ground truth grid, and the part of the trajectory on that floor coloured by frame number.

    panovocc synth work/building --building
    panovocc gt work/building work/building/gt.npz
    python scripts/floor_plans.py work/building/gt.npz work/building/traj.txt docs/figures/building_floors.png
    python scripts/floor_plans.py work/building/gt.npz work/building/traj.txt docs/figures/building_stairs.png \
        --x-range 0,16 --width-px 1400

Floors are the grid's layers with the most ``floor`` voxels (``evaluation.show.floor_layers``); each plan shows
per column the highest occupied voxel under 1.9 m above that floor (walls, doors, furniture, stairs), else the
floor. A pose is drawn on the highest floor at least 1 m below the camera.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("grid", type=Path, help="ground truth grid (.npz) of the scene")
    ap.add_argument("traj", type=Path, help="its trajectory (SCENE/traj.txt, NICE-SLAM or TUM)")
    ap.add_argument("out", type=Path, help="PNG to write")
    ap.add_argument("--width-px", type=int, default=2000)
    ap.add_argument("--title", default=None)
    ap.add_argument("--x-range", default=None, metavar="X0,X1", help="only this part of the x axis (metres)")
    args = ap.parse_args()
    x_range = None if args.x_range is None else tuple(float(v) for v in args.x_range.split(","))

    from panovocc_cli.evaluation.show import floor_plans_figure
    from panovocc_cli.io.figures import write_png
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.poses import read_poses

    fig = floor_plans_figure(read_grid(args.grid), read_poses(args.traj), args.title, args.width_px,
                             x_range=x_range)
    write_png(fig, args.out)
    print(args.out)


if __name__ == "__main__":
    main()
