"""GPU check of the clip segmenter (run by scripts/gpu_check_clip.sh on a machine with CUDA).

1. The tiny randomly initialised open_clip ViT of tests/clip_helpers.py, written to a folder and loaded through
   ``--segmenter clip:FOLDER``: the logits of a 128 x 256 panorama on CUDA match the CPU's (largest
   difference <= TOL_LOGIT in logit units, i.e. 40 x cosine; argmax equal on >= 99.5% of the pixels).
2. The same for a randomly initialised ViT-B-16 (the default architecture; no weights needed), written the
   same way, on a 256 x 512 panorama (cube faces at 224 px), plus its time per 1024 x 512 frame on CUDA.

Prints one JSON object (also written to $OUT/gpu_check_clip.json when OUT is set); exit status 0 when
every check passed, 1 otherwise, 3 without CUDA.
"""

import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

TOL_LOGIT = 0.05
MIN_AGREE = 0.995
VOCAB = ["wall", "floor", "ceiling", "bed", "sofa", "chair", "table", "window"]


def main() -> int:
    import torch

    from clip_helpers import cpu_cuda_difference, smooth_erp, write_tiny_clip
    from panovocc_cli.semantics import _torch_compat

    open_clip = _torch_compat.import_open_clip()
    import torchvision

    report = {"torch": torch.__version__, "torchvision": torchvision.__version__, "open_clip": open_clip.__version__,
              "torchvision_shim": _torch_compat.shim_active(), "cuda": torch.cuda.is_available()}
    if not torch.cuda.is_available():
        print(json.dumps(report))
        return 3
    report["device"] = torch.cuda.get_device_name(0)
    # float32 everywhere: no TF32 in matmuls or convolutions (the CPU reference has none)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        tiny = write_tiny_clip(Path(tmp) / "tiny", seed=0)
        d = cpu_cuda_difference(f"clip:{tiny},size=64,device=cpu", f"clip:{tiny},size=64,device=cuda",
                                smooth_erp(128), VOCAB)
        d["pass"] = d["max_abs_diff"] <= TOL_LOGIT and d["argmax_agree"] >= MIN_AGREE
        report["tiny"] = d
        ok &= d["pass"]

        cfg = open_clip.get_model_config("ViT-B-16")
        base = write_tiny_clip(Path(tmp) / "vitb16", seed=0, config=cfg)
        d = cpu_cuda_difference(f"clip:{base},device=cpu", f"clip:{base},device=cuda", smooth_erp(256), VOCAB)
        d["pass"] = d["max_abs_diff"] <= TOL_LOGIT and d["argmax_agree"] >= MIN_AGREE
        report["vit_b_16_random"] = d
        ok &= d["pass"]

        from panovocc_cli.semantics.registry import build_segmenter

        seg = build_segmenter(f"clip:{base},device=cuda")
        frame = smooth_erp(512, seed=1)
        seg.logits(frame, VOCAB)
        torch.cuda.synchronize()
        times = []
        for _ in range(5):
            t = time.perf_counter()
            seg.logits(frame, VOCAB)
            torch.cuda.synchronize()
            times.append(time.perf_counter() - t)
        report["vit_b_16_ms_per_1024x512_frame_cuda"] = round(1e3 * sorted(times)[2], 1)
    report["pass"] = bool(ok)
    text = json.dumps(report, indent=2)
    print(text)
    if os.environ.get("OUT"):
        Path(os.environ["OUT"], "gpu_check_clip.json").write_text(text + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
