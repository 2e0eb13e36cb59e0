#!/usr/bin/env bash
# Two captures of one home along different trajectories, each mapped alone, then merged (docs/sharding.md,
# "Merging captures"): FreeOcc IoU / mIoU (eval8) of capture A, capture B and their merge against the mesh
# ground truth. Usage: scripts/merge_two_captures.sh WORK [SEED] [WIDTH]
set -euo pipefail
W=${1:?usage: scripts/merge_two_captures.sh WORK [SEED] [WIDTH]}
SEED=${2:-1}
WIDTH=${3:-512}
P=${PANOVOCC:-.venv/bin/panovocc}
PY=${PYTHON:-.venv/bin/python}
mkdir -p "$W"
$P synth "$W/scene" --seed "$SEED" --frames 120 --overwrite
# capture A: the even poses of the first two thirds of the trajectory; capture B: the odd poses of the last two
# thirds, 0.25 m lower (another day, another rig height): different viewpoints, overlapping in the middle
$PY - "$W" <<'PYEOF'
import sys
import numpy as np
from panovocc_cli.io.poses import read_poses, write_poses
w = sys.argv[1]
T = read_poses(f"{w}/scene/traj.txt")
a = T[0:80:2].copy()
b = T[41:120:2].copy()
b[:, 2, 3] -= 0.25
write_poses(f"{w}/traj_a.txt", a)
write_poses(f"{w}/traj_b.txt", b)
PYEOF
$P render "$W/scene" "$W/seq_a" --traj "$W/traj_a.txt" --width "$WIDTH" --seed 0 --overwrite
$P render "$W/scene" "$W/seq_b" --traj "$W/traj_b.txt" --width "$WIDTH" --seed 0 --overwrite
$P gt "$W/scene" "$W/gt.npz" --overwrite
$P map "$W/seq_a" "$W/map_a" --origin 0,0,0 --overwrite --quiet
$P map "$W/seq_b" "$W/map_b" --origin 0,0,0 --overwrite --quiet
$P merge "$W/map_a" "$W/map_b" "$W/map_ab" --renumber --overwrite --quiet
for m in map_a map_b map_ab; do
  $P eval "$W/$m/prediction.npz" "$W/gt.npz" --classes eval8 --json | $PY -c "import json, sys; d = json.load(sys.stdin); \
print(f'$m: IoU {d[\"iou\"]:.2f} mIoU {d[\"miou\"]:.2f} (FreeOcc, eval8)')"
done
