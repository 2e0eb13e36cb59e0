#!/usr/bin/env bash
# GPU check of the clip segmenter: CUDA logits == CPU logits (tiny random ViT and a random ViT-B-16), and
# the ViT-B-16's time per 1024x512 frame on CUDA. Needs torch with CUDA and numpy + numba; installs the
# pure-Python open_clip stack (open_clip_torch, ftfy, wcwidth, regex, tqdm) from local wheels when
# open_clip is missing: WHEELS=folder of wheels (default work/gpu_wheels), into work/gpu_site (nothing
# system-wide). Usage: scripts/gpu_check_clip.sh   (exit 0 = pass, 1 = mismatch, 3 = no CUDA)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python3}
export PYTHONPATH="$PWD/work/gpu_site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
if ! "$PY" -c "from panovocc_cli.semantics._torch_compat import import_open_clip; import_open_clip()" >/dev/null 2>&1; then
  WHEELS=${WHEELS:-work/gpu_wheels}
  "$PY" -m pip install -q --no-deps --no-index --find-links "$WHEELS" --target work/gpu_site \
    open_clip_torch ftfy wcwidth regex tqdm
fi
exec "$PY" scripts/gpu_check_clip.py
