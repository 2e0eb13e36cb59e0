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
