#!/bin/sh
# How much a map's IoU moves when the whole trajectory is moved by a millimetre or two (issue 22, docs/slam.md
# "Translation and rotation apart": where the map sits against the 8 cm lattice). For each scene K of a
# `make bench-jitter` folder W (W/homeK.gt.npz, W/homeK.{clean,realistic}: 512x256 renders), each depth and
# each offset: `traj perturb SEQ/poses.txt --offset X,Y,Z` (no noise: every camera moved rigidly), `map --poses`
# (--segmenter none, default export) and `eval`. Prints "scene depth offset IoU".
#   sh scripts/lattice_shift_iou.sh W [K ...]          (run from the repository; default K: 2 4)
set -e
W=${1:?usage: lattice_shift_iou.sh W [K ...]}
[ $# -gt 1 ] && shift 1 || set -- 2 4
P="$(pwd)/.venv/bin/panovocc"; PY="$(pwd)/.venv/bin/python"
iou() { "$P" eval "$1" "$2" --json | "$PY" -c "import sys, json; print(round(json.load(sys.stdin)['iou'], 2))"; }
for K in "$@"; do
  for D in clean realistic; do
    S="$W/home$K.$D"
    for O in 0,0,0 0,0,-0.002 0,0,-0.001 0,0,0.001 0,0,0.002 -0.002,0,0 -0.001,0,0 0.001,0,0 0.002,0,0; do
      T="$W/shift.home$K.$D.$O"
      "$P" traj perturb "$S/poses.txt" "$T.poses.txt" --offset "$O" --overwrite >/dev/null
      "$P" map "$S" "$T.map" --poses "$T.poses.txt" --segmenter none --checkpoint-every 0 --quiet --overwrite >/dev/null
      echo "home$K $D $O $(iou "$T.map/prediction.npz" "$W/home$K.gt.npz")"
    done
  done
done
