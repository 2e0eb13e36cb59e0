"""ERP tiling: a perspective segmenter whose answer is a function of the viewing direction, run on tiles of a
panorama and blended back, gives that function at every ERP pixel (seams and poles included)."""

import math

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.semantics.segmenter import Segmenter
from panovocc_cli.semantics.tiling import ErpTiler, TiledSegmenter, tiling_rig

AXES = np.concatenate([np.eye(3), -np.eye(3)])  # classes +x +y +z -x -y -z (panorama camera frame)
GAIN = 4.0


def direction_image(width: int) -> np.ndarray:
    """An ERP image whose colour encodes each pixel's ray: rgb = round(127.5 (d + 1))."""
    return np.clip(np.floor(127.5 * (ray_directions(width) + 1.0) + 0.5), 0, 255).astype(np.uint8)


class DirectionSegmenter(Segmenter):
    """Perspective segmenter: decodes each pixel's viewing direction (panorama frame) from its colour and
    answers ``GAIN * d . axis_c`` for the six axis classes: a known function of the direction."""

    spec = "direction"

    def __init__(self):
        self.calls = []

    def logits(self, rgb, vocab, *, frame_id=None):
        self.calls.append((rgb.shape, frame_id))
        d = rgb.astype(np.float64) / 127.5 - 1.0
        return (GAIN * d @ AXES.T).astype(np.float32)


def expected(width: int) -> np.ndarray:
    return GAIN * ray_directions(width) @ AXES.T


@pytest.mark.parametrize("kind,n_views", [("cube", 6), ("tangent", 18)])
def test_reassembly_equals_the_direction_function(kind, n_views):
    rig = tiling_rig(kind, 64)
    assert len(rig) == n_views
    seg = TiledSegmenter(DirectionSegmenter(), rig)
    out = seg.logits(direction_image(256), [f"c{i}" for i in range(6)], frame_id=7)
    want = expected(256)
    assert out.shape == (128, 256, 6) and out.dtype == np.float32
    # colour quantisation (1/127.5) and bilinear resampling twice: within 1% of the range
    assert np.abs(out - want).max() < 0.05 * GAIN / 4
    # argmax = the dominant axis of the ray wherever it is not a near-tie
    s = np.sort(want, axis=-1)
    clear = s[..., -1] - s[..., -2] > 0.1
    assert np.array_equal(out.argmax(-1)[clear], want.argmax(-1)[clear])
    assert seg.inner.calls == [((64, 64, 3), 7)] * n_views  # frame_id passed on, one call per view


def test_seam_and_poles_are_continuous():
    out = TiledSegmenter(DirectionSegmenter(), tiling_rig("cube", 64)).logits(direction_image(256), list("abcdef"))
    # longitude seam: column W-1 and column 0 are neighbours (as close as any two neighbouring columns)
    seam = np.abs(out[:, -1] - out[:, 0]).max()
    inner = np.abs(np.diff(out, axis=1)).max()
    assert seam <= inner + 1e-3
    # poles: every pixel of the top row looks (almost) straight up (-y), of the bottom row straight down
    assert np.all(out[0].argmax(-1) == 4) and np.all(out[-1].argmax(-1) == 1)
    assert np.abs(out[0, :, 4] - GAIN * math.cos(math.pi / 256)).max() < 0.05


def test_blend_weights_partition_unity_and_constants_survive_exactly():
    for kind, fov in (("cube", None), ("cube", math.pi / 2), ("tangent", None)):
        tiler = ErpTiler(tiling_rig(kind, 48, fov), 128)
        total = np.zeros(128 * 64)
        for idx, x, y, w in tiler.cover:
            np.add.at(total, idx, w)
            assert np.all(w > 0) and np.all((x >= -0.5) & (x <= 47.5) & (y >= -0.5) & (y <= 47.5))
        assert np.allclose(total, 1.0)  # every ERP pixel covered, weights sum to 1
        views = [np.broadcast_to(np.array([1.5, -2.0, 0.25], np.float32), (48, 48, 3)) for _ in tiler.rig]
        assert np.allclose(tiler.merge(views), [1.5, -2.0, 0.25], atol=1e-6)


def test_overlap_is_blended_not_switched():
    """Where two cube faces of 110 deg overlap, an ERP pixel takes from both: a segmenter that answers each
    view's own index gives a fraction strictly between two indices there, and whole indices at face centres."""
    rig = tiling_rig("cube", 64)
    tiler = ErpTiler(rig, 256)
    views = [np.full((64, 64, 1), float(k), np.float32) for k in range(len(rig))]
    out = tiler.merge(views)[..., 0]
    # row 64 is the horizon; column 128 looks along +z (front, 0), column 192 along +x (right, 1)
    assert out[64, 128] == pytest.approx(0.0, abs=1e-6) and out[64, 192] == pytest.approx(1.0, abs=1e-6)
    mid = out[64, 160]  # azimuth 45 deg: the front / right cube edge
    assert 0.0 < mid < 1.0 and mid == pytest.approx(0.5, abs=0.05)


def test_split_samples_the_panorama_along_each_view_ray():
    rig = tiling_rig("tangent", 32)
    tiler = ErpTiler(rig, 128)
    views = tiler.split(direction_image(128))
    for view, img in zip(rig, views):
        rays = view.camera.rays() @ view.R_cam_view.T
        assert np.abs(img.astype(float) / 127.5 - 1.0 - rays).max() < 0.06


def test_a_strided_panorama_that_is_not_exactly_2_to_1():
    """The map loop hands the segmenter rgb[::s, ::s]; H = 4, s = 3 gives 2 x 3 pixels from 4 x 8. Any
    longitude x latitude grid is tiled with its own pixel centres."""
    from panovocc_cli.geometry.erp import angles_to_ray, pixel_to_angles

    h, w = 33, 67
    th, ph = pixel_to_angles(np.arange(w)[None, :], np.arange(h)[:, None], w, h)
    d = angles_to_ray(*np.broadcast_arrays(th, ph))
    rgb = np.clip(np.floor(127.5 * (d + 1.0) + 0.5), 0, 255).astype(np.uint8)
    out = TiledSegmenter(DirectionSegmenter(), tiling_rig("cube", 32)).logits(rgb, list("abcdef"))
    assert out.shape == (h, w, 6)
    assert np.abs(out - GAIN * d @ AXES.T).max() < 0.1


def test_bad_inputs():
    seg = TiledSegmenter(DirectionSegmenter(), tiling_rig("cube", 16))
    with pytest.raises(PanovoccError):
        seg.logits(np.zeros((10, 30, 3), np.uint8), ["a"])
    with pytest.raises(PanovoccError):
        tiling_rig("icosahedron", 16)
    with pytest.raises(PanovoccError):
        tiling_rig("cube", 16, math.pi)
    tiler = ErpTiler(tiling_rig("cube", 16), 64)
    with pytest.raises(PanovoccError):
        tiler.merge([np.zeros((16, 16, 2))] * 5)
    with pytest.raises(PanovoccError):
        tiler.split(np.zeros((16, 64, 3), np.uint8))
