"""``clip``: a training-free dense CLIP segmenter (NACLIP's recipe) on panoramas, built on ``open_clip``.

CLIP is trained to match a whole image with a caption; its patch tokens do not localise. NACLIP
(Hajimiri et al., "Pay Attention to Your Neighbours", WACV 2025) makes them do so without training by
changing only the last block of the vision transformer:

* **attention**: key-key similarity ``k k^T / sqrt(d)`` instead of query-key, plus a Gaussian kernel over
  the patch grid (``exp(-|p - q|^2 / (2 std^2))``, std 5 patches) added to the attention logits, so each
  patch attends to its spatial neighbourhood; the class token neither gives nor takes the kernel;
* **reduced block**: the block's output is that attention alone (after ``out_proj``): no residual
  connection, no feed-forward network;
* every token (not only the class token) goes through ``ln_post`` and the projection; patch features
  are L2-normalised and compared by cosine with the vocabulary's text embeddings, each the normalised
  mean over the 80 OpenAI ImageNet prompt templates ("a photo of a {}.", ...) of the normalised text
  features; logits = 40 x cosine (NACLIP's logit scale), bilinearly upsampled from the patch grid.

Not carried over from NACLIP: its sliding-window inference inside an image (the panorama's tiles play
that role) and its PAMR post-processing. The panorama is cut into overlapping pinhole tiles
(:mod:`.tiling`, cube faces of 110 deg by default), each tile is one forward pass at the tile size
(positional embeddings interpolated bicubically to the tile's patch grid), and the tiles' logits are
blended back on the ERP grid.

Spec (``--segmenter``), parsed by :func:`parse_clip_spec`::

    clip                            ViT-B-16 with OpenAI's weights, from open_clip's cache
    clip:MODEL[@TAG]                an open_clip model name with a pretrained tag, from the cache
    clip:MODEL@/path/weights.bin    an open_clip model name with a local checkpoint (.bin .pt .pth .safetensors)
    clip:/path/folder               a folder with open_clip_config.json and its weights (a downloaded
                                    Hugging Face open_clip repository)

followed by options ``,key=value``: ``rig=cube|tangent|none`` (``none``: the ERP image itself, resized to
size x 2 size), ``size=N`` (tile side in pixels, a multiple of the patch size; default the model's input
size), ``fov=DEG`` (tile field of view), ``device=auto|cpu|cuda``, ``std=PATCHES`` (Gaussian kernel),
``scale=S`` (logit scale). Nothing is downloaded: without weights on disk the spec is refused with a one-line
message saying how to provide them.

The spec is validated and the weights located when the segmenter is built (:class:`ClipSegmenter`);
the network loads on the first frame. Device ``auto`` is CUDA when available, else CPU; on CPU the
results are deterministic for a given thread count.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import PanovoccError
from .segmenter import Segmenter

PREFIX = "clip"
DEFAULT_MODEL = "ViT-B-16"
DEFAULT_TAG = "openai"
#: NACLIP's defaults: Gaussian kernel std (patches) and the logit scale applied to cosine similarities.
GAUSSIAN_STD = 5.0
LOGIT_SCALE = 40.0
RIG_CHOICES = ("cube", "tangent", "none")
DEVICES = ("auto", "cpu", "cuda")
WEIGHT_SUFFIXES = (".bin", ".pt", ".pth", ".safetensors")
CONFIG_NAME = "open_clip_config.json"

HOW_TO_PROVIDE = ("pass --segmenter clip:MODEL@/path/to/weights.bin (an open_clip checkpoint) or "
                  "clip:/path/to/folder (open_clip_config.json + weights), or fetch them once into open_clip's "
                  "cache with: python -c \"import open_clip; open_clip.create_model('{model}', pretrained='{tag}')\"")


@dataclass(frozen=True)
class ClipSpec:
    """A parsed ``clip`` segmenter spec (see the module docstring).

    model : open_clip model name, or None for a folder; weights : a pretrained tag, an absolute checkpoint
    path, or an absolute folder path (``model`` None); rig, size (None = the model's input size), fov_deg
    (None = the rig's default), device, std (patches), scale: the options
    """

    model: str | None
    weights: str
    rig: str = "cube"
    size: int | None = None
    fov_deg: float | None = None
    device: str = "auto"
    std: float = GAUSSIAN_STD
    scale: float = LOGIT_SCALE

    @property
    def is_folder(self) -> bool:
        return self.model is None

    @property
    def is_tag(self) -> bool:
        return self.model is not None and not os.path.isabs(self.weights)

    def __str__(self) -> str:
        head = f"{PREFIX}:{self.weights}" if self.is_folder else f"{PREFIX}:{self.model}@{self.weights}"
        opts = [f"rig={self.rig}"] + ([f"size={self.size}"] if self.size is not None else [])
        opts += [f"fov={self.fov_deg:g}"] if self.fov_deg is not None else []
        opts += [f"device={self.device}"]
        opts += [f"std={self.std:g}"] if self.std != GAUSSIAN_STD else []
        opts += [f"scale={self.scale:g}"] if self.scale != LOGIT_SCALE else []
        return head + "," + ",".join(opts)


def is_clip(spec: str) -> bool:
    """Whether ``spec`` names this segmenter (``clip`` or ``clip:...``)."""
    s = spec.strip()
    return s == PREFIX or s.startswith(PREFIX + ":") or s.startswith(PREFIX + ",")


def _looks_like_path(s: str) -> bool:
    return "/" in s or os.sep in s or s.endswith(WEIGHT_SUFFIXES) or s.startswith(("~", "."))


def parse_clip_spec(spec: str) -> ClipSpec:
    """Parse a ``clip`` spec (no file is opened; paths are made absolute).

    Raises
    ------
    PanovoccError
        An unknown option, a malformed value or an empty model / weights part.
    """
    s = spec.strip()
    if not is_clip(s):
        raise PanovoccError(f"not a clip segmenter spec: {spec!r}")
    body = s[len(PREFIX):].lstrip(":")
    opts = {}
    parts = body.split(",")
    while len(parts) > 1 and "=" in parts[-1]:  # trailing key=value options (a path may hold commas)
        k, v = parts.pop().split("=", 1)
        opts[k.strip()] = v.strip()
    head = ",".join(parts).strip()
    if not head:
        model, weights = DEFAULT_MODEL, DEFAULT_TAG
    elif "@" in head:
        model, weights = (x.strip() for x in head.split("@", 1))
        if not model or not weights:
            raise PanovoccError(f"segmenter {spec!r}: expected clip:MODEL@TAG or clip:MODEL@/path/to/weights")
    elif _looks_like_path(head):
        model, weights = None, head
    else:
        model, weights = head, ""
    if weights and _looks_like_path(weights):
        weights = str(Path(weights).expanduser().resolve())
    out = ClipSpec(model, weights)
    known = {"rig", "size", "fov", "device", "std", "scale"}
    for k, v in sorted(opts.items()):
        if k not in known:
            raise PanovoccError(f"segmenter {spec!r}: unknown option {k!r} (expected {', '.join(sorted(known))})")
        try:
            if k == "rig":
                if v not in RIG_CHOICES:
                    raise ValueError(f"expected {' | '.join(RIG_CHOICES)}")
                out = replace(out, rig=v)
            elif k == "device":
                if v not in DEVICES:
                    raise ValueError(f"expected {' | '.join(DEVICES)}")
                out = replace(out, device=v)
            elif k == "size":
                n = int(v)
                if not 16 <= n <= 4096:
                    raise ValueError("expected 16..4096 pixels")
                out = replace(out, size=n)
            elif k == "fov":
                f = float(v)
                if not 10.0 <= f <= 170.0:
                    raise ValueError("expected 10..170 degrees")
                out = replace(out, fov_deg=f)
            else:
                f = float(v)
                if not (math.isfinite(f) and f > 0):
                    raise ValueError("expected a positive number")
                out = replace(out, **{k: f})
        except ValueError as e:
            raise PanovoccError(f"segmenter {spec!r}: bad {k}={v!r} ({e})") from None
    return out


# ---------------------------------------------------------------------------------------------
# locating weights (no download, ever)


def _cached_tag_weights(open_clip, model: str, tag: str) -> tuple[str | None, dict]:
    """The cached checkpoint of ``model`` with pretrained ``tag`` (None when not cached) and the tag's config."""
    cfg = open_clip.get_pretrained_cfg(model, tag) or {}
    if "file" in cfg:
        return (cfg["file"] if os.path.isfile(cfg["file"]) else None), cfg
    hub = cfg.get("hf_hub", "")
    if hub:
        try:
            from huggingface_hub import try_to_load_from_cache
        except ImportError:
            try_to_load_from_cache = None
        if try_to_load_from_cache is not None:
            if hub.endswith("/"):  # open_clip's convention: the repository's default weights file
                repo, names = hub[:-1], ["open_clip_model.safetensors", "open_clip_pytorch_model.bin"]
            else:
                repo, filename = os.path.split(hub)
                names = ([filename[:-4] + ".safetensors"] if filename.endswith((".bin", ".pth")) else []) + [filename]
            cache = os.environ.get("HF_HUB_CACHE") or (os.path.join(os.environ["HF_HOME"], "hub")
                                                       if os.environ.get("HF_HOME") else None)
            for name in names:
                hit = try_to_load_from_cache(repo, name, cache_dir=cache)
                if isinstance(hit, str) and os.path.isfile(hit):
                    return hit, cfg
    url = cfg.get("url", "")
    if url:
        path = os.path.join(os.path.expanduser("~/.cache/clip"), os.path.basename(url))
        if os.path.isfile(path):
            return path, cfg
    return None, cfg


def _folder_checkpoint(folder: Path) -> Path | None:
    """The weights file of an open_clip folder (the names open_clip looks for), or None."""
    for name in ("open_clip_model.safetensors", "open_clip_pytorch_model.safetensors", "open_clip_pytorch_model.bin",
                 "open_clip_pytorch_model.pth", "model.safetensors", "pytorch_model.bin"):
        if (folder / name).is_file():
            return folder / name
    found = sorted(p for suf in WEIGHT_SUFFIXES for p in folder.glob("*" + suf))
    return found[0] if found else None


@dataclass(frozen=True)
class ResolvedWeights:
    """Where a spec's network comes from: ``create_model`` arguments. ``name``: model name or ``local-dir:``
    folder; ``checkpoint``: file path or None (folder); ``quick_gelu``: the tag's activation flag."""

    name: str
    checkpoint: str | None
    quick_gelu: bool = False


def resolve_weights(spec: ClipSpec) -> ResolvedWeights:
    """Locate the spec's weights on disk (open_clip's cache for a tag; never a download).

    Raises
    ------
    PanovoccError
        open_clip missing, an unknown model or tag, a missing file or folder, or no cached weights: one line
        saying how to provide them.
    """
    from ._torch_compat import import_open_clip

    open_clip = import_open_clip()
    if spec.is_folder:
        folder = Path(spec.weights)
        if not folder.is_dir():
            raise PanovoccError("CLIP weights folder not found (expected open_clip_config.json and its weights)",
                                folder)
        if not (folder / CONFIG_NAME).is_file():
            raise PanovoccError(f"no {CONFIG_NAME} in the CLIP weights folder", folder)
        if _folder_checkpoint(folder) is None:
            raise PanovoccError(f"no weights file ({', '.join(WEIGHT_SUFFIXES)}) in the CLIP weights folder", folder)
        return ResolvedWeights("local-dir:" + str(folder), None)
    model = spec.model
    if model not in open_clip.list_models():
        raise PanovoccError(f"unknown open_clip model {model!r} in segmenter 'clip:{model}' (e.g. ViT-B-16, ViT-L-14; "
                            "open_clip.list_models() lists them)")
    if os.path.isabs(spec.weights):
        if not os.path.isfile(spec.weights):
            raise PanovoccError("CLIP weights file not found", spec.weights)
        return ResolvedWeights(model, spec.weights)
    tags = open_clip.list_pretrained_tags_by_model(model)
    tag = spec.weights or (DEFAULT_TAG if DEFAULT_TAG in tags else (tags[0] if tags else ""))
    if tag not in tags:
        raise PanovoccError(f"open_clip has no pretrained tag {tag!r} for {model} (tags: {', '.join(tags) or 'none'}); "
                            + HOW_TO_PROVIDE.format(model=model, tag=tags[0] if tags else "TAG"))
    path, cfg = _cached_tag_weights(open_clip, model, tag)
    if path is None:
        raise PanovoccError(f"no CLIP weights for {model}@{tag} on this machine: " + HOW_TO_PROVIDE.format(model=model, tag=tag))
    return ResolvedWeights(model, path, bool(cfg.get("quick_gelu", False)))


# ---------------------------------------------------------------------------------------------
# the network


def gaussian_attention_bias(grid_h: int, grid_w: int, std: float):
    """NACLIP's neighbourhood term ``(1 + N, 1 + N)`` float32 torch tensor, N = grid_h grid_w patches:
    ``exp(-|p - q|^2 / (2 std^2))`` between patches p, q (grid units, row-major), 0 in the class token's
    row and column."""
    import torch

    r, c = np.meshgrid(np.arange(grid_h, dtype=np.float64), np.arange(grid_w, dtype=np.float64), indexing="ij")
    pos = np.stack([r.ravel(), c.ravel()], axis=1)
    d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)
    out = np.zeros((1 + len(pos), 1 + len(pos)), np.float32)
    out[1:, 1:] = np.exp(-d2 / (2.0 * std * std))
    return torch.from_numpy(out)


class DenseClip:
    """An open_clip CLIP model answering per-patch text similarities (NACLIP's modified last block).

    Parameters
    ----------
    model : an open_clip ``CLIP`` whose ``visual`` is a plain ``VisionTransformer`` (``nn.MultiheadAttention``
        blocks, class-token pooling, no attentional pooler)
    tokenizer : open_clip tokenizer of the model
    device : torch device string
    std, scale : Gaussian kernel std (patches) and logit scale
    """

    def __init__(self, model, tokenizer, device: str = "cpu", std: float = GAUSSIAN_STD, scale: float = LOGIT_SCALE):
        import torch

        visual = getattr(model, "visual", None)
        blocks = getattr(getattr(visual, "transformer", None), "resblocks", None)
        if (blocks is None or not hasattr(visual, "conv1") or getattr(visual, "attn_pool", None) is not None
                or not isinstance(getattr(blocks[-1], "attn", None), torch.nn.MultiheadAttention)):
            raise PanovoccError("the clip segmenter needs a ViT CLIP model with standard attention blocks "
                                "(e.g. ViT-B-16, ViT-L-14); this model's vision tower is not one")
        self.model = model.to(device).eval()
        self.tokenizer = tokenizer
        self.device = device
        self.std = float(std)
        self.scale = float(scale)
        self.patch = tuple(int(p) for p in visual.patch_size)
        from open_clip.model import get_model_preprocess_cfg

        pp = get_model_preprocess_cfg(model)
        from open_clip.constants import OPENAI_DATASET_MEAN, OPENAI_DATASET_STD

        self.mean = torch.tensor(pp.get("mean", OPENAI_DATASET_MEAN), dtype=torch.float32, device=device).view(1, 3, 1, 1)
        self.std_rgb = torch.tensor(pp.get("std", OPENAI_DATASET_STD), dtype=torch.float32, device=device).view(1, 3, 1, 1)
        size = visual.image_size
        self.input_size = int(size[0] if isinstance(size, (tuple, list)) else size)
        self._text: dict[tuple, object] = {}
        self._bias: dict[tuple, object] = {}

    def text_features(self, vocab: Sequence[str]):
        """``(C, D)`` float32 torch tensor: per class, the normalised mean of its normalised prompt features."""
        import torch
        from open_clip.zero_shot_metadata import OPENAI_IMAGENET_TEMPLATES

        key = tuple(vocab)
        if key not in self._text:
            feats = []
            with torch.inference_mode():
                for name in vocab:
                    words = name.replace("_", " ").replace("-", " ")
                    tokens = self.tokenizer([t(words) for t in OPENAI_IMAGENET_TEMPLATES]).to(self.device)
                    f = self.model.encode_text(tokens).float()
                    f = f / f.norm(dim=-1, keepdim=True)
                    f = f.mean(dim=0)
                    feats.append(f / f.norm())
            self._text[key] = torch.stack(feats)
        return self._text[key]

    def _pos_embed(self, gh: int, gw: int):
        """Positional embeddings ``(1 + gh gw, width)`` for a ``gh`` x ``gw`` patch grid (bicubic resize of the
        model's square grid when it differs)."""
        import torch.nn.functional as F

        pos = self.model.visual.positional_embedding
        n = pos.shape[0] - 1
        g0, g1 = self.model.visual.grid_size
        if (gh, gw) == (g0, g1) and n == g0 * g1:
            return pos
        grid = pos[1:].reshape(1, g0, g1, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(grid.float(), size=(gh, gw), mode="bicubic", align_corners=False)
        return torch_cat(pos[:1], grid.permute(0, 2, 3, 1).reshape(gh * gw, -1).to(pos.dtype))

    def patch_features(self, images):
        """Normalised patch features ``(B, gh, gw, D)`` float32 of images ``(B, 3, h, w)`` float in [0, 1]
        (h, w multiples of the patch size), through NACLIP's modified last block."""
        import torch
        import torch.nn.functional as F

        v = self.model.visual
        b, _, h, w = images.shape
        gh, gw = h // self.patch[0], w // self.patch[1]
        x = (images - self.mean) / self.std_rgb
        x = v.conv1(x.to(v.conv1.weight.dtype))                      # (B, width, gh, gw)
        x = x.reshape(b, x.shape[1], -1).permute(0, 2, 1)             # (B, N, width)
        cls = v.class_embedding.to(x.dtype).view(1, 1, -1).expand(b, 1, -1)
        x = torch.cat([cls, x], dim=1) + self._pos_embed(gh, gw).to(x.dtype)
        x = v.ln_pre(x)
        blocks = v.transformer.resblocks
        batch_first = getattr(v.transformer, "batch_first", True)
        if not batch_first:
            x = x.transpose(0, 1)
        for blk in blocks[:-1]:
            x = blk(x)
        if not batch_first:
            x = x.transpose(0, 1)
        last = blocks[-1]
        attn = last.attn
        y = last.ln_1(x)
        q_k_v = F.linear(y, attn.in_proj_weight, attn.in_proj_bias)
        _, k, val = q_k_v.chunk(3, dim=-1)
        heads = attn.num_heads
        n, width = y.shape[1], y.shape[2]
        hd = width // heads
        k = k.reshape(b, n, heads, hd).transpose(1, 2)                # (B, heads, N, hd)
        val = val.reshape(b, n, heads, hd).transpose(1, 2)
        key = (gh, gw)
        if key not in self._bias:
            self._bias[key] = gaussian_attention_bias(gh, gw, self.std).to(self.device)
        logits = torch.matmul(k, k.transpose(-1, -2)) * (hd ** -0.5) + self._bias[key].to(k.dtype)
        out = torch.matmul(torch.softmax(logits, dim=-1), val)       # (B, heads, N, hd)
        out = attn.out_proj(out.transpose(1, 2).reshape(b, n, width))  # no residual, no MLP
        feats = v.ln_post(out[:, 1:]) @ v.proj                        # every patch token, projected
        feats = feats.float()
        feats = feats / feats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return feats.reshape(b, gh, gw, -1)

    def logits_images(self, images_uint8: Sequence[np.ndarray], vocab: Sequence[str], size: tuple[int, int]) -> list:
        """Per-pixel logits of images.

        Parameters
        ----------
        images_uint8 : list of (h, w, 3) uint8 images (all the same size)
        vocab : list of C class names
        size : (h', w') the network's input size, multiples of the patch size (images are resized
            bilinearly to it when they differ)

        Returns
        -------
        list of (h, w, C) float32: ``scale`` x cosine(patch feature, class text feature), bilinearly
        upsampled from the patch grid to the image size (``align_corners=False``)
        """
        import torch
        import torch.nn.functional as F

        if not images_uint8:
            return []
        with torch.inference_mode():
            feats, (h, w) = self._patch_features_of(images_uint8, size)   # (B, gh, gw, D)
            t = self.text_features(vocab)
            sims = torch.einsum("bijd,cd->bcij", feats, t) * self.scale
            up = F.interpolate(sims, size=(h, w), mode="bilinear", align_corners=False)
            out = up.permute(0, 2, 3, 1).contiguous().cpu().numpy().astype(np.float32)
        return list(out)

    def features_images(self, images_uint8: Sequence[np.ndarray], size: tuple[int, int]) -> list:
        """Per-pixel dense features of images: the normalised patch features (CLIP's joint image-text space,
        the model's embedding dimension D), bilinearly upsampled from the patch grid to the image size like
        the logits of :meth:`logits_images`. list of (h, w, D) float32."""
        import torch
        import torch.nn.functional as F

        if not images_uint8:
            return []
        with torch.inference_mode():
            feats, (h, w) = self._patch_features_of(images_uint8, size)
            up = F.interpolate(feats.permute(0, 3, 1, 2), size=(h, w), mode="bilinear", align_corners=False)
            out = up.permute(0, 2, 3, 1).contiguous().cpu().numpy().astype(np.float32)
        return list(out)

    def encode_text(self, texts: Sequence[str]) -> np.ndarray:
        """Texts in the space of :meth:`features_images`: ``(n, D)`` float32 unit vectors, each the normalised mean
        of its prompt-template features (:meth:`text_features`)."""
        return self.text_features(list(texts)).cpu().numpy().astype(np.float32)

    def _patch_features_of(self, images_uint8, size):
        """(patch features (B, gh, gw, D) of the images resized to ``size``, the images' (h, w))."""
        import torch
        import torch.nn.functional as F

        h, w = images_uint8[0].shape[:2]
        arr = np.stack([np.asarray(im, np.uint8) for im in images_uint8])
        x = torch.from_numpy(arr).to(self.device).permute(0, 3, 1, 2).float() / 255.0
        if (h, w) != tuple(size):
            x = F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False, antialias=True)
        return self.patch_features(x), (h, w)


def torch_cat(a, b):
    import torch

    return torch.cat([a, b], dim=0)


def pick_device(device: str) -> str:
    """``auto`` -> ``cuda`` when torch sees a GPU, else ``cpu``; ``cuda`` without one is an error."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise PanovoccError("segmenter option device=cuda, but torch sees no CUDA device (use device=cpu or auto)")
    return device


def _bad_checkpoint_errors() -> tuple:
    """What loading a file that is not a checkpoint of the model raises (torch.load's unpickler, safetensors)."""
    import pickle

    errors = [RuntimeError, ValueError, KeyError, OSError, EOFError, pickle.UnpicklingError]
    try:
        from safetensors import SafetensorError

        errors.append(SafetensorError)
    except ImportError:
        pass
    return tuple(errors)


def load_dense_clip(spec: ClipSpec, device: str | None = None) -> DenseClip:
    """Build the network of ``spec`` on ``device`` (default: the spec's, ``auto`` resolved)."""
    from ._torch_compat import import_open_clip

    open_clip = import_open_clip()
    where = resolve_weights(spec)
    dev = pick_device(device or spec.device)
    bad_checkpoint = _bad_checkpoint_errors()
    try:
        if where.checkpoint is None:
            model = open_clip.create_model(where.name, device=dev, require_pretrained=True)
        else:
            model = open_clip.create_model(where.name, pretrained=where.checkpoint, device=dev,
                                           force_quick_gelu=where.quick_gelu, require_pretrained=True)
        tokenizer = open_clip.get_tokenizer(where.name)
    except bad_checkpoint as e:  # a checkpoint that does not fit the model, or is no checkpoint at all
        msg = str(e).splitlines()[0][:300] if str(e) else type(e).__name__
        raise PanovoccError(f"cannot load CLIP weights for {spec.model or 'the folder'} ({msg})",
                            where.checkpoint or spec.weights) from None
    return DenseClip(model, tokenizer, dev, spec.std, spec.scale)


class ClipSegmenter(Segmenter):
    """The ``clip`` segmenter on ERP frames (or on perspective images with ``rig=none``).

    Built from a spec string (validated and weights located at once; the network loads on the first
    call). ``logits(rgb (H, 2H, 3) uint8, vocab)`` -> ``(H, 2H, C)`` float32: NACLIP logits of the rig's
    tiles blended on the ERP grid (:mod:`.tiling`), or of the whole image resized to ``size x 2 size``
    with ``rig=none``. ``logits_views(views, vocab)`` runs a batch of perspective images.
    """

    def __init__(self, spec: str | ClipSpec):
        self.cfg = spec if isinstance(spec, ClipSpec) else parse_clip_spec(spec)
        self.weights = resolve_weights(self.cfg)
        self.spec = str(self.cfg)
        self._net: DenseClip | None = None
        self._tiled = None

    def prepare(self) -> None:
        """Load the network (weights and device checked: a bad checkpoint or ``device=cuda`` without a GPU
        fails here, before a command writes anything)."""
        self.net

    @property
    def net(self) -> DenseClip:
        """The network (loaded on first use)."""
        if self._net is None:
            self._net = load_dense_clip(self.cfg)
        return self._net

    def tile_size(self) -> int:
        """Tile side in pixels: the spec's ``size`` or the model's input size, a multiple of the patch size."""
        n = self.cfg.size or self.net.input_size
        p = self.net.patch[0]
        if n % p:
            raise PanovoccError(f"segmenter {self.spec!r}: size={n} is not a multiple of the model's patch size {p}")
        return n

    def logits_views(self, views: Sequence[np.ndarray], vocab: Sequence[str]) -> list:
        """Logits ``(h, w, C)`` float32 of perspective images ``(h, w, 3)`` uint8 (one batch, at the tile size)."""
        n = self.tile_size()
        return self.net.logits_images(list(views), vocab, (n, n))

    def features_views(self, views: Sequence[np.ndarray], vocab=None) -> list:
        """Dense features ``(h, w, D)`` float32 of perspective images (one batch, at the tile size)."""
        n = self.tile_size()
        return self.net.features_images(list(views), (n, n))

    def features(self, rgb: np.ndarray, *, frame_id=None) -> np.ndarray:
        """Per-pixel dense CLIP features ``(H, W, D)`` float32 of one ERP frame: the tiles' features (NACLIP's
        last block, normalised, upsampled) blended on the ERP grid by the same tiler as the logits (``rig=none``:
        the whole image). D is the model's embedding dimension (512 for ViT-B-16)."""
        rgb = self._check_rgb(rgb)
        if self.cfg.rig == "none":
            return self.net.features_images([rgb], self._whole_size(rgb))[0]
        tiler = self._tiler().tiler(rgb.shape[1], rgb.shape[0])
        return tiler.merge(self.features_views(tiler.split(rgb)))

    def text_encoder(self):
        """CLIP's text tower (prompt-template averaged, :meth:`DenseClip.encode_text`): the space of
        :meth:`features`."""
        return self.net.encode_text

    def _check_rgb(self, rgb):
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise PanovoccError(f"expected an RGB image (H, W, 3) uint8, got {rgb.dtype} {rgb.shape}")
        return rgb

    def _whole_size(self, rgb) -> tuple[int, int]:
        n = self.tile_size()
        wide = abs(rgb.shape[1] - 2 * rgb.shape[0]) <= 2  # a panorama (or a strided one)
        return (n, 2 * n) if wide else (n, n)

    def _tiler(self):
        if self._tiled is None:
            from .tiling import TiledSegmenter, tiling_rig

            fov = None if self.cfg.fov_deg is None else math.radians(self.cfg.fov_deg)
            self._tiled = TiledSegmenter(self, tiling_rig(self.cfg.rig, self.tile_size(), fov))
        return self._tiled

    def logits(self, rgb: np.ndarray, vocab: Sequence[str], *, frame_id=None) -> np.ndarray:
        """Per-pixel logits ``(H, W, C)`` float32 of one ERP frame (see :class:`~.segmenter.Segmenter`)."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise PanovoccError(f"expected an RGB image (H, W, 3) uint8, got {rgb.dtype} {rgb.shape}")
        if self.cfg.rig == "none":
            return self.net.logits_images([rgb], vocab, self._whole_size(rgb))[0]
        return self._tiler().logits(rgb, vocab, frame_id=frame_id)
