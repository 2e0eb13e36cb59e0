"""The clip segmenter on CUDA gives the CPU's logits (tiny random ViT). Skipped without a CUDA device;
scripts/gpu_check_clip.sh runs it with a ViT-B-16 as well."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from clip_helpers import cpu_cuda_difference, smooth_erp, write_tiny_clip  # noqa: E402


def _has_cuda() -> bool:
    try:
        import torch
    except ImportError:  # pragma: no cover
        return False
    return torch.cuda.is_available()


@pytest.mark.cuda
@pytest.mark.skipif(not _has_cuda(), reason="needs a CUDA device")
def test_cuda_logits_match_cpu(tmp_path):
    import torch

    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    tiny = write_tiny_clip(tmp_path / "tiny")
    d = cpu_cuda_difference(f"clip:{tiny},size=64,device=cpu", f"clip:{tiny},size=64,device=cuda", smooth_erp(64),
                            ["wall", "floor", "bed", "sofa"])
    assert d["max_abs_diff"] <= 0.05 and d["argmax_agree"] >= 0.995, d


def test_the_comparison_itself_on_two_cpu_builds(tmp_path):
    """The helper the GPU check relies on: two CPU builds of one folder agree exactly; another seed does not."""
    tiny = write_tiny_clip(tmp_path / "tiny")
    d = cpu_cuda_difference(f"clip:{tiny},size=64,device=cpu", f"clip:{tiny},size=64,device=cpu", smooth_erp(32),
                            ["wall", "bed"])
    assert d["max_abs_diff"] == 0.0 and d["argmax_agree"] == 1.0 and d["shape"] == [32, 64, 2]
    other = write_tiny_clip(tmp_path / "other", seed=1)
    d = cpu_cuda_difference(f"clip:{tiny},size=64,device=cpu", f"clip:{other},size=64,device=cpu", smooth_erp(32),
                            ["wall", "bed"])
    assert d["max_abs_diff"] > 0.05
