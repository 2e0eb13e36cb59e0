#!/bin/sh
# True-pose against estimated-pose maps of the Results scenes (docs/slam.md, "The final refinement: ATE and
# maps" and "The front end alone over the whole building"): per scene, the front end's refined poses
# (slam.run.run_slam_poses with SlamParams(**JSON)), the map with the true poses and the map with the estimate
# SE(3)-aligned to them (--poses-align se3), both --segmenter none, scored against the mesh ground truth, and the
# estimate's ATE (SE(3)-aligned, mm). Prints "SCENE true IoU slam IoU ate RMSE".
#   sh scripts/slam_iou_table.sh WORK [JSON [SCENE ...]]   (run from the repository; makes the scenes in WORK
#   when missing; JSON: SlamParams fields, default '{}'; SCENE: 0 1 h0 h1 h2 h3 h4, the default all seven)
#   sh scripts/slam_iou_table.sh W '{"loop_linked": 0}' h3      (house 3 with every loop candidate verified)
set -e
W=${1:?usage: slam_iou_table.sh WORK [JSON [SCENE ...]]}; J=${2:-"{}"}
[ $# -gt 2 ] && shift 2 || set -- 0 1 h0 h1 h2 h3 h4
P="$(pwd)/.venv/bin/panovocc"; PY="$(pwd)/.venv/bin/python"
mkdir -p "$W"; cd "$W"
iou() { "$P" eval "$1" "$2" --json | "$PY" -c "import sys, json; print(round(json.load(sys.stdin)['iou'], 2))"; }
for S in "$@"; do
  case $S in h*) K=${S#h}; sc=$S; q=q$S; synth="--house --seed $K --frames 150";; *) K=$S; sc=s$S; q=q$S; synth="--seed $K";; esac
  [ -f $sc/traj.txt ] || "$P" synth $sc $synth >/dev/null 2>&1
  [ -f $q/meta.json ] || "$P" render $sc $q --width 512 --noise realistic --seed $K >/dev/null 2>&1
  [ -f gt$S.npz ] || "$P" gt $sc gt$S.npz >/dev/null 2>&1
  rm -rf est$S ma$S
  "$PY" -c "from panovocc_cli.runtime import setup; setup(); import json, sys; from panovocc_cli.slam import SlamParams; from panovocc_cli.slam.run import run_slam_poses; run_slam_poses('$q', 'est$S', SlamParams(**json.loads(sys.argv[1])))" "$J" >/dev/null 2>&1
  [ -f mt$S/prediction.npz ] || "$P" map $q mt$S --segmenter none --checkpoint-every 0 --quiet >/dev/null 2>&1
  "$P" map $q ma$S --poses est$S/poses.txt --poses-align se3 --segmenter none --checkpoint-every 0 --quiet >/dev/null 2>&1
  "$P" traj eval est$S/poses.txt $q/poses.txt --json est$S/ate.json >/dev/null 2>&1
  ate=$("$PY" -c "import json; print(round(1e3 * json.load(open('est$S/ate.json'))['ate_m']['rmse'], 2))")
  echo "$S true $(iou mt$S/prediction.npz gt$S.npz) slam $(iou ma$S/prediction.npz gt$S.npz) ate $ate"
done
