#!/bin/sh
# True-pose against estimated-pose maps of the Results scenes (docs/slam.md, "The final refinement: ATE and
# maps" and "The front end alone over the whole building"): per scene, the front end's refined poses
# (slam.run.run_slam_poses), the map with the true poses and the map with the estimate SE(3)-aligned to them
# (--poses-align se3), both --segmenter none, scored against the mesh ground truth. Prints "SCENE true IoU slam IoU".
#   sh scripts/slam_iou_table.sh WORK        (makes the scenes in WORK when missing; run from the repository)
set -e
W=${1:?usage: slam_iou_table.sh WORK}
P="$(pwd)/.venv/bin/panovocc"; PY="$(pwd)/.venv/bin/python"
mkdir -p "$W"; cd "$W"
iou() { "$P" eval "$1" "$2" --json | "$PY" -c "import sys, json; print(round(json.load(sys.stdin)['iou'], 2))"; }
for S in 0 1 h0 h1 h2 h3 h4; do
  case $S in h*) K=${S#h}; sc=$S; q=q$S; synth="--house --seed $K --frames 150";; *) K=$S; sc=s$S; q=q$S; synth="--seed $K";; esac
  [ -f $sc/traj.txt ] || "$P" synth $sc $synth >/dev/null 2>&1
  [ -f $q/meta.json ] || "$P" render $sc $q --width 512 --noise realistic --seed $K >/dev/null 2>&1
  [ -f gt$S.npz ] || "$P" gt $sc gt$S.npz >/dev/null 2>&1
  rm -rf est$S ma$S
  "$PY" -c "from panovocc_cli.runtime import setup; setup(); from panovocc_cli.slam.run import run_slam_poses; run_slam_poses('$q', 'est$S')" >/dev/null 2>&1
  [ -f mt$S/prediction.npz ] || "$P" map $q mt$S --segmenter none --checkpoint-every 0 --quiet >/dev/null 2>&1
  "$P" map $q ma$S --poses est$S/poses.txt --poses-align se3 --segmenter none --checkpoint-every 0 --quiet >/dev/null 2>&1
  echo "$S true $(iou mt$S/prediction.npz gt$S.npz) slam $(iou ma$S/prediction.npz gt$S.npz)"
done
