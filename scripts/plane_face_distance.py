"""How far each scene's floor and ceiling lie from the nearest voxel face of the 8 cm lattice (issue 22, docs/slam.md
"Translation and rotation apart": the planes a centimetre of pose jitter smears over a face).

    python scripts/plane_face_distance.py [--homes 0,1,2,3,4,5] [--houses 0] [--buildings 0] [--voxel 0.08]

Each scene as ``panovocc synth`` makes it (its seeded offset, ``datasets.layout.lattice_offset``): the floor's
height and the ceiling's (floor + ceiling height), their position inside their voxel layer (mm above its lower
face) and the distance to the nearer face; a building (``synth --building``), each storey's.
"""

from __future__ import annotations

import argparse

from panovocc_cli.datasets.building import generate_building
from panovocc_cli.datasets.home import generate_scene
from panovocc_cli.datasets.house import generate_house


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--homes", default="0,1,2,3,4,5")
    ap.add_argument("--houses", default="0")
    ap.add_argument("--buildings", default="0")
    ap.add_argument("--voxel", type=float, default=0.08)
    a = ap.parse_args(argv)
    h = a.voxel
    print("| scene | floor: mm into its layer | floor: mm to the nearer face | ceiling: mm into its layer | "
          "ceiling: mm to the nearer face |")
    print("|---|---|---|---|---|")
    rows = []
    for s in (s for s in a.homes.split(",") if s):
        g = generate_scene(int(s), None, 2, None)
        rows.append((f"home {s}", g["floor_z"], g["ceiling_height"]))
    for s in (s for s in a.houses.split(",") if s):
        g = generate_house(int(s), None, 2, None)
        rows.append((f"house {s}", g["floor_z"], g["ceiling_height"]))
    for s in (s for s in a.buildings.split(",") if s):
        g = generate_building(int(s), None, None, 2, None)
        rows += [(f"building {s}, floor {k}", z, g["ceiling_height"]) for k, z in enumerate(g["floor_heights"])]
    for name, floor, ceiling in rows:
        cells = []
        for z in (floor, floor + ceiling):
            into = (z % h) * 1000.0
            cells += [f"{into:.1f}", f"{min(into, h * 1000.0 - into):.1f}"]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
