"""Perspective segmenters on panoramas: ERP frame -> overlapping pinhole tiles -> logits back on the ERP.

A segmenter trained on perspective photographs sees a panorama's distortion (stretched rows near the
poles, the seam at longitude +-180 deg) if it is run on the ERP image itself. Here the frame is cut
into pinhole views of a :class:`~panovocc_cli.geometry.cameras.ViewRig` sharing the panorama's centre
(cube faces or a denser set of tangent planes, with overlap), the segmenter runs on each view, and its
logits are resampled back onto every ERP pixel and blended:

* **split** (:meth:`ErpTiler.split`): each view pixel's ray, rotated into the panorama's camera frame,
  meets the ERP image at a continuous ``(u, v)`` (:func:`geometry.erp.project`); colours are bilinear,
  longitude wraps around, rows beyond the poles repeat the first / last row;
* **merge** (:meth:`ErpTiler.merge`): each ERP pixel's ray is projected into every view in front of
  which it lies (:meth:`PinholeCamera.project`); inside a view the logits are sampled bilinearly (view
  borders clamp). The views' samples are averaged with weights that fall linearly to 0 toward each
  view's border (``feather``: the outer fraction of the view's half-width in tangent space), so the
  blend is continuous across seams; a ray no view covers with a positive weight (possible only for
  rigs without overlap) takes the view whose axis is closest to it. The poles are ordinary rays: the
  up / down faces (or polar tangent planes) cover them with full weight.

Rigs (:func:`tiling_rig`): ``cube`` (six faces, default field of view 110 deg: 10 deg overlap past
each cube edge) and ``tangent`` (18 views of 90 deg by default: 8 around the horizon, 4 at +-50 deg
pitch offset by 45 deg, and the two poles).

:class:`TiledSegmenter` wraps any :class:`~.segmenter.Segmenter` this way. Pure numpy; no files.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import PanovoccError
from ..geometry.cameras import PinholeCamera, RigView, ViewRig, view_rotation
from .segmenter import Segmenter

RIGS = ("cube", "tangent")
#: Default field of view of each rig's views, degrees.
DEFAULT_FOV_DEG = {"cube": 110.0, "tangent": 90.0}
#: Default blending ramp: the outer 30% of each view's half-width (tangent space) fades to 0.
DEFAULT_FEATHER = 0.3


def tiling_rig(kind: str, size: int, fov_rad: float | None = None) -> ViewRig:
    """The views a panorama is cut into.

    Parameters
    ----------
    kind : ``cube`` (front, right, back, left, up, down) or ``tangent`` (18 views: azimuths 0, 45, ...,
        315 deg at pitch 0; 45, 135, 225, 315 deg at pitch +50 and -50 deg; the two poles)
    size : int, each view's width = height in pixels
    fov_rad : float or None, each view's horizontal = vertical field of view in radians (None:
        :data:`DEFAULT_FOV_DEG`); a cube needs more than 90 deg for its faces to overlap

    Returns
    -------
    rig : ViewRig of square pinhole views (OpenCV axes, shared centre, no roll except at the poles,
        where the view's x axis follows the panorama's x axis)
    """
    if kind not in RIGS:
        raise PanovoccError(f"unknown tiling rig {kind!r}: expected {' or '.join(RIGS)}")
    fov = math.radians(DEFAULT_FOV_DEG[kind]) if fov_rad is None else float(fov_rad)
    if not 0.0 < fov < math.pi:
        raise PanovoccError(f"tile field of view {math.degrees(fov):g} deg; expected in (0, 180)")
    cam = PinholeCamera.from_fov(size, size, fov)
    if kind == "cube":
        dirs = [("front", 0, 0), ("right", 90, 0), ("back", 180, 0), ("left", 270, 0), ("up", 0, 90), ("down", 0, -90)]
    else:
        dirs = [(f"h{a:03d}", a, 0) for a in range(0, 360, 45)]
        dirs += [(f"u{a:03d}", a, 50) for a in (45, 135, 225, 315)]
        dirs += [(f"d{a:03d}", a, -50) for a in (45, 135, 225, 315)]
        dirs += [("up", 0, 90), ("down", 0, -90)]
    views = []
    for name, az, pitch in dirs:
        a, p = math.radians(az), math.radians(pitch)
        R = view_rotation(a, p)
        if az % 90 == 0 and pitch % 90 == 0:
            R = np.round(R) + 0.0  # axis-aligned faces: entries exactly 0 or +-1
        views.append(RigView(name, cam, a, p, R))
    return ViewRig(tuple(views))


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray, wrap_u: bool) -> np.ndarray:
    """Bilinear samples ``(..., C)`` float64 of ``image (h, w, C)`` at continuous pixel ``(u, v)`` (centres at
    integers); ``wrap_u``: columns wrap around (ERP longitude), else they clamp; rows always clamp."""
    h, w = image.shape[:2]
    u0 = np.floor(u)
    v0 = np.floor(v)
    fu = (u - u0)[..., None]
    fv = (v - v0)[..., None]
    u0 = u0.astype(np.int64)
    v0 = v0.astype(np.int64)
    if wrap_u:
        c0, c1 = u0 % w, (u0 + 1) % w
    else:
        c0, c1 = np.clip(u0, 0, w - 1), np.clip(u0 + 1, 0, w - 1)
    r0, r1 = np.clip(v0, 0, h - 1), np.clip(v0 + 1, 0, h - 1)
    top = image[r0, c0] * (1.0 - fu) + image[r0, c1] * fu
    bot = image[r1, c0] * (1.0 - fu) + image[r1, c1] * fu
    return top * (1.0 - fv) + bot * fv


class ErpTiler:
    """Lookup tables between an ERP image of ``width`` x ``width / 2`` and the views of ``rig``.

    Parameters
    ----------
    rig : ViewRig, pinhole views sharing the panorama's centre (``R_cam_view``: view axes in the
        panorama's camera frame)
    width : int, ERP width in pixels
    height : int or None, ERP height (None: width / 2). Any size is an equirectangular grid of longitude x
        latitude (a panorama subsampled by a stride that does not divide it is not exactly 2:1)
    feather : float in (0, 1], the outer fraction of each view's half-width (in tangent space,
        ``max(|x/z|, |y/z|)``) over which its blending weight falls linearly from 1 to 0

    Attributes
    ----------
    erp_u, erp_v : (V, h, w) float64, continuous ERP column / row hit by each view pixel's ray
    cover : list of V tuples ``(index (n,) int64 flat ERP pixel, x (n,), y (n,) float64 continuous view
        pixel, weight (n,) float64 normalised so that every ERP pixel's weights sum to 1)``
    """

    def __init__(self, rig: ViewRig, width: int, feather: float = DEFAULT_FEATHER, height: int | None = None):
        from ..geometry.erp import angles_to_ray, check_erp_size, pixel_to_angles, project

        if not 0.0 < feather <= 1.0:
            raise PanovoccError(f"tile feather {feather}; expected in (0, 1]")
        if len(rig) == 0:
            raise PanovoccError("a tiling rig needs at least one view")
        self.rig = rig
        if height is None:
            self.width, self.height = check_erp_size(width)
        else:
            self.width, self.height = int(width), int(height)
            if self.width < 2 or self.height < 1:
                raise PanovoccError(f"panorama of {self.width}x{self.height} pixels is too small to tile")
        us, vs = [], []
        for view in rig:
            rays_cam = view.camera.rays() @ view.R_cam_view.T  # view pixel rays, panorama frame
            u, v, _ = project(rays_cam, self.width, self.height)
            us.append(u)
            vs.append(v)
        self.erp_u, self.erp_v = np.stack(us), np.stack(vs)

        theta, phi = pixel_to_angles(np.arange(self.width)[None, :], np.arange(self.height)[:, None], self.width,
                                     self.height)
        rays = angles_to_ray(*np.broadcast_arrays(theta, phi)).reshape(-1, 3)  # ERP pixel rays, panorama frame
        n_pix = len(rays)
        raw = []
        total = np.zeros(n_pix)
        best_axis = np.full(n_pix, -np.inf)
        best_view = np.zeros(n_pix, np.int64)
        for k, view in enumerate(rig):
            cam = view.camera
            p = rays @ view.R_cam_view  # the rays in the view's frame
            z = p[:, 2]
            better = z > best_axis
            best_axis[better], best_view[better] = z[better], k
            front = z > 1e-9
            idx = np.flatnonzero(front)
            x, y, _ = cam.project(p[idx])
            inside = (x >= -0.5) & (x <= cam.width - 0.5) & (y >= -0.5) & (y <= cam.height - 0.5)
            idx, x, y = idx[inside], x[inside], y[inside]
            # tangent-space distance to the border: 1 at the centre, 0 on the border
            t_max_x = max(cam.cx + 0.5, cam.width - 0.5 - cam.cx) / cam.fx
            t_max_y = max(cam.cy + 0.5, cam.height - 0.5 - cam.cy) / cam.fy
            tx = np.abs(x - cam.cx) / cam.fx / t_max_x
            ty = np.abs(y - cam.cy) / cam.fy / t_max_y
            w = np.clip((1.0 - np.maximum(tx, ty)) / feather, 0.0, 1.0)
            raw.append((idx, x, y, w))
            np.add.at(total, idx, w)
        orphan = total <= 0.0  # no positive weight anywhere: the view whose axis is closest
        self.cover = []
        for k, (idx, x, y, w) in enumerate(raw):
            w = w.copy()
            mine = orphan[idx] & (best_view[idx] == k)
            w[mine] = 1.0
            keep = w > 0.0
            idx, x, y, w = idx[keep], x[keep], y[keep], w[keep]
            self.cover.append((idx, x, y, w))
        total = np.zeros(n_pix)
        for idx, _, _, w in self.cover:
            np.add.at(total, idx, w)
        if np.any(total <= 0.0):  # a ray behind every view (a rig with a hole)
            raise PanovoccError(f"the {len(rig)} tiling views leave {int((total <= 0).sum())} ERP pixels uncovered")
        self.cover = [(idx, x, y, w / total[idx]) for idx, x, y, w in self.cover]

    @property
    def view_shape(self) -> tuple[int, int]:
        """``(h, w)`` of the first view (all views of the built-in rigs share it)."""
        return self.rig[0].camera.shape

    def split(self, rgb: np.ndarray) -> list[np.ndarray]:
        """The views of an ERP colour image.

        Parameters
        ----------
        rgb : (H, W, 3) uint8, the panorama

        Returns
        -------
        views : list of V arrays (h, w, 3) uint8, bilinear (rounded), in rig order
        """
        rgb = np.asarray(rgb)
        if rgb.shape[:2] != (self.height, self.width):
            raise PanovoccError(f"image is {rgb.shape[1]}x{rgb.shape[0]}, the tiler was built for "
                                f"{self.width}x{self.height}")
        img = rgb.astype(np.float64)
        return [np.clip(np.floor(_bilinear(img, self.erp_u[k], self.erp_v[k], True) + 0.5), 0, 255).astype(np.uint8)
                for k in range(len(self.rig))]

    def merge(self, view_logits: Sequence[np.ndarray]) -> np.ndarray:
        """Blend the views' logits back onto the ERP grid.

        Parameters
        ----------
        view_logits : V arrays (h, w, C) float, one per view in rig order

        Returns
        -------
        logits : (H, W, C) float32, the feathered average of the views' bilinear samples at each ERP pixel
        """
        if len(view_logits) != len(self.rig):
            raise PanovoccError(f"{len(view_logits)} tile outputs for {len(self.rig)} views")
        c = np.shape(view_logits[0])[-1]
        out = np.zeros((self.height * self.width, c), np.float64)
        for (idx, x, y, w), lg in zip(self.cover, view_logits):
            lg = np.asarray(lg, np.float64)
            if lg.ndim != 3 or lg.shape[-1] != c:
                raise PanovoccError(f"tile logits of shape {lg.shape}; expected (h, w, {c})")
            out[idx] += w[:, None] * _bilinear(lg, x, y, False)
        return out.reshape(self.height, self.width, c).astype(np.float32)


class TiledSegmenter(Segmenter):
    """Any perspective segmenter on ERP frames through :class:`ErpTiler` (tables built per ERP size).

    Parameters
    ----------
    inner : Segmenter that takes a pinhole view ``(h, w, 3)`` uint8 and returns ``(h, w, C)`` logits; if it
        has ``logits_views(views, vocab)`` (a batch: list of views -> list of logits) that is used instead
    rig : ViewRig, the views (:func:`tiling_rig`)
    feather : float, see :class:`ErpTiler`
    """

    def __init__(self, inner: Segmenter, rig: ViewRig, feather: float = DEFAULT_FEATHER):
        self.inner = inner
        self.rig = rig
        self.feather = float(feather)
        self.spec = getattr(inner, "spec", "")
        self._tilers: dict[tuple[int, int], ErpTiler] = {}

    def tiler(self, width: int, height: int | None = None) -> ErpTiler:
        """The (cached) :class:`ErpTiler` for ERP frames of ``width`` x ``height`` (default width / 2) pixels."""
        key = (int(width), int(height if height is not None else width // 2))
        if key not in self._tilers:
            self._tilers[key] = ErpTiler(self.rig, key[0], self.feather, height=key[1])
        return self._tilers[key]

    def logits(self, rgb: np.ndarray, vocab: Sequence[str], *, frame_id=None) -> np.ndarray:
        """ERP logits ``(H, W, C)`` float32 (see :class:`~.segmenter.Segmenter`); ``frame_id`` is passed on."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or abs(rgb.shape[1] - 2 * rgb.shape[0]) > 2:
            raise PanovoccError(f"expected an ERP colour image (H, 2H, 3) (a strided one within 2 pixels of "
                                f"2:1), got shape {rgb.shape}")
        tiler = self.tiler(rgb.shape[1], rgb.shape[0])
        views = tiler.split(rgb)
        batch = getattr(self.inner, "logits_views", None)
        if batch is not None:
            outs = batch(views, vocab)
        else:
            outs = [self.inner.logits(v, vocab, frame_id=frame_id) for v in views]
        return tiler.merge(outs)
