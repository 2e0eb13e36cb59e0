"""``panovocc synth``: write a procedural indoor scene in Replica's format, with a camera trajectory.

The scenes: a small home (:mod:`~panovocc_cli.datasets.home`), a house of rooms off a corridor
(:mod:`~panovocc_cli.datasets.house`, ``--house``). They are built from the layout primitives of
:mod:`~panovocc_cli.datasets.layout`, the furnished rooms of :mod:`~panovocc_cli.datasets.rooms` (furniture:
:mod:`~panovocc_cli.datasets.furniture`) and the trajectories of :mod:`~panovocc_cli.datasets.trajectory`.
This module holds the command's options and its runner.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED, MAX_SEED, option, validate_config
from ..errors import PanovoccError


@dataclass
class SynthConfig:
    """Options of ``panovocc synth``.

    out: scene folder to write (Replica layout); seed: random seed; rooms: number of rooms (None:
    2 or 3 drawn from the seed; 6-8 with ``house``; rooms a floor with ``building``, None: as many as
    2,500 m² need); frames: trajectory poses (None: 60, 300 with ``house``, one every 0.2 m with
    ``building``); offset: (x, y, z) metres the home is moved from the origin (a user-chosen placement
    relative to the voxel lattice; None: drawn from the seed); house: a house-scale home
    (:mod:`panovocc_cli.datasets.house`); building: floors of rooms off corridors joined by a staircase
    (:mod:`panovocc_cli.datasets.building`); floors: the building's floors (None: 3); descend: the building's
    walk comes back down to the ground floor's entrance.
    """

    out: Path = option(argument=True, metavar="SCENE", help="Scene folder to write (Replica layout: "
                       "habitat/mesh_semantic.ply, habitat/info_semantic.json, traj.txt).")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Random seed; the same seed gives the same files.")
    rooms: int | None = option(None, min=1, max=60, help="Number of rooms, 1-6 (default: 2 or 3 from the seed); "
                               "with --house 6-8 off a corridor (default: 6, 7 or 8 from the seed); with --building "
                               "2-60 a floor (default: as many as 2,500 m² of floor need).")
    frames: int | None = option(None, min=2, show_default="60; 300 with --house; one every 0.2 m with --building",
                                help="Number of trajectory poses.")
    offset: tuple[float, float, float] | None = option(
        None, cli_type=str, parse=lambda text: parse_offset(text), metavar="X,Y,Z",
        help="X,Y,Z metres: move the home (laid out from the origin) by this offset instead of the seeded one "
             "(e.g. 0,0,0 puts the floor on a voxel face).")
    house: bool = option(False, help="A house-scale home: 6-8 furnished rooms on both sides of a corridor, a long "
                                     "trajectory through all of them (the embedded Pan-Holo split's scene).")
    building: bool = option(False, help="A building: floors of furnished rooms off a corridor, joined by a dog-leg "
                                        "staircase; one walk through every room of every floor, up the stairs.")
    floors: int | None = option(None, min=2, max=8, show_default="3", help="Floors of the building (--building only).")
    descend: bool = option(False, help="With --building: after the top floor's rooms, walk back down every flight to "
                                       "the ground floor and along its corridor to the entrance (a floor left for the "
                                       "floors above is seen again: loop closure across floors).")
    overwrite: bool = option(False, help="Replace a previous panovocc scene in SCENE (never any other folder).")


def parse_offset(text: str) -> tuple[float, float, float]:
    """``"X,Y,Z"`` (metres, finite) -> a 3-tuple of floats; `PanovoccError` naming the option otherwise."""
    parts = text.split(",")
    try:
        xyz = tuple(float(p) for p in parts)
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not all(np.isfinite(xyz)) or max(abs(x) for x in xyz) > 1e4:
        raise PanovoccError(f"--offset: expected X,Y,Z in metres (three finite numbers), got {text!r}")
    return xyz


def run_synth(cfg: SynthConfig) -> dict:
    """Write ``cfg.out`` as a Replica-format scene plus ``traj.txt``; returns a summary dict."""
    from dataclasses import replace

    from ..io.atomic import atomic_dir, check_output
    from ..io.poses import write_poses
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from .replica import TRAJ_NAME, write_replica_scene
    from .trajectory import path_length

    cfg = validate_config(cfg)  # seed, rooms, frames, floors: the ranges declared on SynthConfig
    if cfg.house and cfg.building:
        raise PanovoccError("--house and --building are two different scenes: give one of them")
    if cfg.floors is not None and not cfg.building:
        raise PanovoccError("--floors only applies with --building")
    if cfg.descend and not cfg.building:
        raise PanovoccError("--descend only applies with --building")
    check_output(cfg.out, "scene", cfg.overwrite)  # as the command line: never replace what synth did not write
    if cfg.building:
        from .building import BUILDING_FLOORS, generate_building

        g = generate_building(cfg.seed, cfg.floors, cfg.rooms, cfg.frames, cfg.offset, descend=cfg.descend)
        cfg = replace(cfg, floors=BUILDING_FLOORS if cfg.floors is None else cfg.floors,
                      frames=len(g["T_world_cam"]))
    elif cfg.house:
        from .house import HOUSE_FRAMES, generate_house

        cfg = replace(cfg, frames=HOUSE_FRAMES if cfg.frames is None else cfg.frames)
        g = generate_house(cfg.seed, cfg.rooms, cfg.frames, cfg.offset)
    else:
        from .home import SMALL_FRAMES, generate_scene

        cfg = replace(cfg, frames=SMALL_FRAMES if cfg.frames is None else cfg.frames)
        g = generate_scene(cfg.seed, cfg.rooms, cfg.frames, cfg.offset)
    with atomic_dir(cfg.out) as tmp:
        write_replica_scene(tmp, g["vertices"], g["quads"], g["face_object"], g["colors"], g["object_classes"])
        write_poses(tmp / TRAJ_NAME, g["T_world_cam"])
        write_run_config(tmp / CONFIG_NAME, cfg)
    corridors = [k for k in g.get("room_kinds", []) if k in ("corridor", "stair")]
    P = g["T_world_cam"][:, :3, 3]
    return {"rooms": len(g["rooms"]) - len(corridors), "corridor": cfg.house, "floors": cfg.floors,
            "floor_area": g.get("floor_area"), "faces": int(len(g["quads"])), "objects": len(g["object_classes"]),
            "classes": sorted({canonical_name(c) for c in g["object_classes"]}), "frames": len(P),
            "path_m": path_length(P if cfg.building else P[:, :2]), "offset": [float(x) for x in g["offset"]]}
