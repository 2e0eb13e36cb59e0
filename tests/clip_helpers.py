"""A tiny, randomly initialised open_clip ViT written to disk the way a user's weights are (no download).

``write_tiny_clip(folder)`` builds the model of :data:`TINY_CONFIG` (vision: 64 px input, patch 16, width 64,
2 layers; text: width 64, 2 layers, the standard 49408-token BPE vocabulary) with ``torch.manual_seed(seed)``
and writes ``folder/open_clip_config.json`` plus ``folder/open_clip_pytorch_model.bin`` (a state dict saved
with ``torch.save``: no safetensors needed), i.e. the layout of a Hugging Face open_clip repository, so
``--segmenter clip:FOLDER`` loads it through the same code as real weights. ``register_tiny_config`` adds
the same architecture to open_clip's model registry under :data:`TINY_NAME` (for ``clip:NAME@/path``).
Also used by scripts/gpu_check_clip.py.
"""

from __future__ import annotations

import json
from pathlib import Path

TINY_NAME = "panovocc-test-tiny-vit"
TINY_CONFIG = {
    "embed_dim": 32,
    "vision_cfg": {"image_size": 64, "layers": 2, "width": 64, "patch_size": 16, "head_width": 32},
    "text_cfg": {"context_length": 77, "vocab_size": 49408, "width": 64, "heads": 2, "layers": 2},
}


def tiny_model(seed: int = 0, config: dict | None = None):
    """The randomly initialised open_clip ``CLIP`` of ``config`` (default :data:`TINY_CONFIG`), on the CPU."""
    import torch

    from panovocc_cli.semantics._torch_compat import import_open_clip

    open_clip = import_open_clip()
    torch.manual_seed(seed)
    return open_clip.CLIP(**(config or TINY_CONFIG)).eval()


def write_tiny_clip(folder, seed: int = 0, config: dict | None = None) -> Path:
    """Write the tiny model into ``folder`` (created); returns the folder."""
    import torch

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    model = tiny_model(seed, config)
    (folder / "open_clip_config.json").write_text(json.dumps({"model_cfg": config or TINY_CONFIG,
                                                              "preprocess_cfg": {}}))
    torch.save(model.state_dict(), folder / "open_clip_pytorch_model.bin")
    return folder


def register_tiny_config(folder) -> str:
    """Add :data:`TINY_CONFIG` to open_clip's registry as :data:`TINY_NAME` (a json file in ``folder``)."""
    from panovocc_cli.semantics._torch_compat import import_open_clip

    open_clip = import_open_clip()
    path = Path(folder) / f"{TINY_NAME}.json"
    path.write_text(json.dumps(TINY_CONFIG))
    if TINY_NAME not in open_clip.list_models():
        open_clip.add_model_config(path)
    return TINY_NAME


def smooth_erp(height: int, seed: int = 0):
    """A (height, 2 height, 3) uint8 panorama of a few smooth colour blobs (a CPU/CUDA comparison image whose
    argmax regions are large, unlike noise)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:height, 0:2 * height] / height
    img = np.zeros((height, 2 * height, 3))
    for _ in range(6):
        cu, cv, r = rng.random() * 2, rng.random(), 0.1 + 0.3 * rng.random()
        img += rng.random(3) * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * r * r))[..., None]
    return np.clip(255 * img / img.max(), 0, 255).astype(np.uint8)


def cpu_cuda_difference(spec_cpu: str, spec_cuda: str, rgb, vocab) -> dict:
    """Logits of one frame through two clip specs (e.g. ``...,device=cpu`` and ``...,device=cuda``): the largest
    absolute difference (logit units: 40 x cosine), the share of pixels whose argmax agrees, and CPU seconds."""
    import time

    import numpy as np

    from panovocc_cli.semantics.registry import build_segmenter

    a_seg, b_seg = build_segmenter(spec_cpu), build_segmenter(spec_cuda)
    a = a_seg.logits(rgb, vocab)
    b_seg.logits(rgb, vocab)  # warm-up (CUDA context, kernels, text features)
    t = time.perf_counter()
    b = b_seg.logits(rgb, vocab)
    return {"max_abs_diff": float(np.abs(a - b).max()), "argmax_agree": float((a.argmax(-1) == b.argmax(-1)).mean()),
            "seconds_second_device": time.perf_counter() - t, "shape": list(a.shape)}
