"""The clip segmenter (NACLIP's dense CLIP) on a tiny randomly initialised open_clip ViT written to disk.

No weights are downloaded: tests/clip_helpers.py writes the model the way a user's weights are laid out, and
the segmenter loads it through the same spec (``clip:FOLDER``, ``clip:MODEL@/path``) a user passes.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cli_helpers import run_cli  # noqa: E402
from clip_helpers import register_tiny_config, tiny_model, write_tiny_clip  # noqa: E402
from semantics_helpers import write_labelled_room  # noqa: E402

from panovocc_cli.errors import PanovoccError  # noqa: E402

try:  # the optional extra; `make test` installs it (.[test,clip])
    from panovocc_cli.semantics._torch_compat import import_open_clip

    import_open_clip()
except PanovoccError as e:  # pragma: no cover
    pytest.skip(str(e), allow_module_level=True)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return write_tiny_clip(tmp_path_factory.mktemp("tinyclip") / "model", seed=0)


def _rgb(h=64, seed=0):
    return (np.random.default_rng(seed).random((h, 2 * h, 3)) * 255).astype(np.uint8)


# --- the import workaround ----------------------------------------------------------------------

def test_open_clip_imports_and_the_shim_only_where_torchvision_cannot_load():
    import torch  # noqa: F401

    from panovocc_cli.semantics import _torch_compat

    open_clip = _torch_compat.import_open_clip()
    assert hasattr(open_clip, "create_model")
    import torchvision.extension as ext

    # the shim is installed exactly when torchvision's compiled extension did not load
    assert _torch_compat.shim_active() == (not ext._has_ops())
    assert not _torch_compat._is_missing_extension_error(RuntimeError("some other failure"))
    assert not _torch_compat._is_missing_extension_error(ImportError("operator torchvision::nms does not exist"))


# --- spec parsing ---------------------------------------------------------------------------------

def test_spec_parsing_defaults_options_and_round_trip(tmp_path):
    from panovocc_cli.semantics.clip import GAUSSIAN_STD, LOGIT_SCALE, parse_clip_spec

    s = parse_clip_spec("clip")
    assert (s.model, s.weights, s.rig, s.size, s.device, s.std, s.scale) == (
        "ViT-B-16", "openai", "cube", None, "auto", GAUSSIAN_STD, LOGIT_SCALE)
    s = parse_clip_spec("clip:ViT-L-14@laion2b_s32b_b82k,rig=tangent,size=336,fov=95,device=cpu,std=3")
    assert (s.model, s.weights, s.rig, s.size, s.fov_deg, s.device, s.std) == (
        "ViT-L-14", "laion2b_s32b_b82k", "tangent", 336, 95.0, "cpu", 3.0)
    assert parse_clip_spec(str(s)) == s
    w = tmp_path / "w,1.bin"  # a comma in a path survives
    s = parse_clip_spec(f"clip:ViT-B-16@{w},size=224")
    assert s.weights == str(w.resolve()) and s.size == 224 and parse_clip_spec(str(s)) == s
    s = parse_clip_spec(f"clip:{tmp_path}")
    assert s.model is None and s.weights == str(tmp_path.resolve())
    for bad in ("clip:ViT-B-16@openai,rig=sphere", "clip:ViT-B-16@openai,size=8", "clip,colour=red",
                "clip:@openai", "clip:ViT-B-16@openai,fov=200", "clip,device=tpu", "clip,std=-1"):
        with pytest.raises(PanovoccError):
            parse_clip_spec(bad)


def test_no_weights_on_disk_is_one_line_saying_how_to_provide_them(tmp_path, monkeypatch):
    from panovocc_cli.semantics.registry import build_segmenter

    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("HOME", str(tmp_path))
    with pytest.raises(PanovoccError) as e:
        build_segmenter("clip:ViT-B-16@openai")
    msg = str(e.value)
    assert "\n" not in msg and "clip:MODEL@/path/to/weights.bin" in msg and "pretrained='openai'" in msg
    for spec, what in ((f"clip:ViT-B-16@{tmp_path}/none.bin", "not found"), (f"clip:{tmp_path}/absent", "not found"),
                       (f"clip:{tmp_path}", "open_clip_config.json"), ("clip:NoSuchNet-9@openai", "unknown open_clip"),
                       ("clip:ViT-B-16@nosuchtag", "no pretrained tag")):
        with pytest.raises(PanovoccError, match=what):
            build_segmenter(spec)


# --- the network ----------------------------------------------------------------------------------

def test_gaussian_bias_closed_form():
    from panovocc_cli.semantics.clip import gaussian_attention_bias

    b = gaussian_attention_bias(3, 4, 2.0).numpy()
    assert b.shape == (13, 13)
    assert np.all(b[0] == 0) and np.all(b[:, 0] == 0)
    assert np.allclose(np.diag(b)[1:], 1.0)
    # patch (0, 0) = token 1 and patch (2, 3) = token 1 + 2 * 4 + 3: squared distance 4 + 9
    assert b[1, 12] == pytest.approx(math.exp(-13 / 8.0), rel=1e-6)
    assert np.array_equal(b, b.T)


def test_last_block_matches_torch_attention_with_key_key_weights():
    """NACLIP's block computed a second, independent way: torch's own MultiheadAttention with the query
    projection replaced by the key projection and the Gaussian kernel as an additive float mask; then no
    residual, no MLP, ln_post and proj on every token."""
    import copy

    import torch

    from panovocc_cli.semantics._torch_compat import import_open_clip
    from panovocc_cli.semantics.clip import DenseClip, gaussian_attention_bias

    open_clip = import_open_clip()
    model = tiny_model(seed=1)
    dense = DenseClip(model, open_clip.get_tokenizer("ViT-B-16"), "cpu", std=1.5)
    img = torch.from_numpy(np.random.default_rng(3).random((2, 3, 64, 96)).astype(np.float32))  # 4 x 6 patches
    got = dense.patch_features(img)
    assert got.shape == (2, 4, 6, 32)

    v = model.visual
    with torch.no_grad():
        x = (img - dense.mean) / dense.std_rgb
        x = v.conv1(x).flatten(2).transpose(1, 2)
        pos = v.positional_embedding
        grid = torch.nn.functional.interpolate(pos[1:].reshape(1, 4, 4, -1).permute(0, 3, 1, 2), size=(4, 6),
                                               mode="bicubic", align_corners=False)
        pos = torch.cat([pos[:1], grid.permute(0, 2, 3, 1).reshape(24, -1)])
        x = torch.cat([v.class_embedding.view(1, 1, -1).expand(2, 1, -1), x], 1) + pos
        x = v.transformer.resblocks[0](v.ln_pre(x))
        last = v.transformer.resblocks[1]
        mha = copy.deepcopy(last.attn)
        w = mha.in_proj_weight.data
        b = mha.in_proj_bias.data
        d = w.shape[1]
        w[:d] = w[d:2 * d]
        b[:d] = b[d:2 * d]
        y = last.ln_1(x)
        out = mha(y, y, y, attn_mask=gaussian_attention_bias(4, 6, 1.5), need_weights=False)[0]
        ref = v.ln_post(out[:, 1:]) @ v.proj
        ref = (ref / ref.norm(dim=-1, keepdim=True)).reshape(2, 4, 6, -1)
    assert torch.allclose(got, ref, atol=2e-5)
    assert torch.allclose(got.norm(dim=-1), torch.ones(2, 4, 6), atol=1e-5)


def test_folder_and_model_at_path_load_the_same_weights(tiny, tmp_path):
    from panovocc_cli.semantics.registry import build_segmenter

    name = register_tiny_config(tmp_path)
    a = build_segmenter(f"clip:{tiny},size=64,device=cpu")
    b = build_segmenter(f"clip:{name}@{tiny / 'open_clip_pytorch_model.bin'},size=64,device=cpu")
    assert a.spec == f"clip:{tiny.resolve()},rig=cube,size=64,device=cpu"
    rgb = _rgb(32)
    la = a.logits(rgb, ["wall", "floor", "bed"])
    assert la.shape == (32, 64, 3) and la.dtype == np.float32 and np.isfinite(la).all()
    assert np.array_equal(la, b.logits(rgb, ["wall", "floor", "bed"]))
    assert np.array_equal(la, a.logits(rgb, ["wall", "floor", "bed"]))  # deterministic
    # logits = 40 cos: bounded; a one-word vocabulary is that word's column
    assert np.abs(la).max() <= 40.0 + 1e-4
    assert np.allclose(a.logits(rgb, ["floor"])[..., 0], la[..., 1], atol=1e-5)
    # another seed's weights answer differently: the file is really read
    other = write_tiny_clip(tmp_path / "other", seed=5)
    assert not np.allclose(build_segmenter(f"clip:{other},size=64").logits(rgb, ["wall", "floor", "bed"]), la)


def test_rig_none_runs_on_the_erp_image_and_a_bad_size_is_refused(tiny):
    from panovocc_cli.semantics.registry import build_segmenter

    seg = build_segmenter(f"clip:{tiny},rig=none,size=32")
    out = seg.logits(_rgb(40), ["wall", "bed"])
    assert out.shape == (40, 80, 2) and np.isfinite(out).all()
    with pytest.raises(PanovoccError, match="multiple of the model's patch size"):
        build_segmenter(f"clip:{tiny},size=40").logits(_rgb(32), ["wall"])


# --- the whole pipeline ---------------------------------------------------------------------------

def test_map_command_with_the_clip_segmenter(tiny, tmp_path, capsys):
    """``panovocc map SEQ OUT --segmenter clip:FOLDER`` end to end: a labelled grid over the vocabulary,
    the resolved spec in config.json, and the same bytes when run again."""
    seq = write_labelled_room(tmp_path / "seq", 128, 2)
    spec = f"clip:{tiny},size=64"
    code, out, err = run_cli(capsys, ["map", seq, tmp_path / "out", "--segmenter", spec, "--vocab",
                                      "wall,floor,bed", "--quiet"])
    assert code == 0, err
    import json

    from panovocc_cli.io.grid import read_grid

    cfg = json.loads((tmp_path / "out" / "config.json").read_text())
    assert cfg["semantic"]["segmenter"] == f"clip:{tiny.resolve()},rig=cube,size=64,device=auto"
    g = read_grid(tmp_path / "out" / "prediction.npz")
    assert list(g.class_names) == ["empty", "wall", "floor", "bed"]
    occ = (g.labels >= 1) & (g.labels <= 3)
    assert occ.sum() > 1000  # classed occupied voxels
    code, _, err = run_cli(capsys, ["map", seq, tmp_path / "again", "--segmenter", spec, "--vocab",
                                    "wall,floor,bed", "--quiet"])
    assert code == 0, err
    assert (tmp_path / "out" / "prediction.npz").read_bytes() == (tmp_path / "again" / "prediction.npz").read_bytes()


def test_map_command_without_weights_exits_2_on_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("HOME", str(tmp_path))
    seq = write_labelled_room(tmp_path / "seq", 64, 1)
    code, out, err = run_cli(capsys, ["map", seq, tmp_path / "out", "--segmenter", "clip", "--quiet"])
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "how" not in out and "clip:MODEL@" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# --- dense features (issue 24) --------------------------------------------------------------------

@pytest.mark.parametrize("rig", ["cube", "none"])
def test_dense_features_through_the_tiling_are_the_logits_before_the_text(tiny, rig):
    """The tiny CLIP's per-pixel features have the model's embedding width, and dotted with the words' text
    features (times the logit scale) they are the logits, through the same tiling and blending."""
    from panovocc_cli.semantics.registry import build_segmenter

    seg = build_segmenter(f"clip:{tiny},rig={rig},size=32")
    rgb = _rgb(32, seed=3)
    f = seg.features(rgb)
    D = seg.net.model.visual.proj.shape[1]
    assert f.shape == (32, 64, D) and f.dtype == np.float32 and np.isfinite(f).all()
    t = seg.text_encoder()(["wall", "bed"])
    assert t.shape == (2, D)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-5)
    lg = seg.logits(rgb, ["wall", "bed"])
    np.testing.assert_allclose(f @ t.T * seg.net.scale, lg, atol=2e-3 * np.abs(lg).max())


def test_map_with_clip_features_is_queried_with_clip_text(tiny, tmp_path, capsys):
    """``map --segmenter clip:FOLDER --features``: the feature channel is filled from CLIP's dense features, and
    ``query`` embeds its text with the same model's text tower."""
    seq = write_labelled_room(tmp_path / "seq", 128, 2)
    code, out, err = run_cli(capsys, ["map", seq, tmp_path / "out", "--segmenter", f"clip:{tiny},size=32",
                                      "--vocab", "wall,floor", "--features", "--feature-dim", "16", "--quiet"])
    assert code == 0, err
    with np.load(tmp_path / "out" / "memory.npz") as z:
        names = z["channel_names"].tolist()
        widths = dict(zip(names, z["channel_widths"].tolist()))
    assert widths["Z"] == 16
    code, out, err = run_cli(capsys, ["query", tmp_path / "out", "a bed", "--json"])
    assert code == 0, err
    import json

    res = json.loads(out)
    assert res["by"] == "features" and res["match"]["voxels_with_features"] > 100
