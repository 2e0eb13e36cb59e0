"""The pinhole (perspective) camera: pixels <-> rays <-> points, radial <-> z-depth.

Camera frame is OpenCV (x right, y down, z forward; CONVENTIONS.md). Intrinsics ``fx, fy, cx, cy`` in
pixels, with OpenCV's pixel convention: the centre of integer pixel ``(col, row)`` is the continuous
coordinate ``(col, row)``, so a centred principal point is ``cx = (W - 1) / 2`` and the image covers
``u`` in ``[-0.5, W - 0.5]`` (docs/conventions.md, "Geometry").

* a point ``(x, y, z)`` projects to ``u = fx x / z + cx``, ``v = fy y / z + cy``;
* pixel ``(u, v)`` looks along ``((u - cx) / fx, (v - cy) / fy, 1)``; normalised, that is its unit ray;
* depth in a pinhole image is **z-depth** (the point's z): ``point = z ((u - cx) / fx, (v - cy) / fy, 1)``;
  a radial depth ``r`` (distance along the ray) is ``r = z * |((u - cx) / fx, (v - cy) / fy, 1)|``.

The numba-callable helpers at the end (:func:`nb_pixel_ray`, :func:`nb_project`) are the same formulas for
compiled per-pixel loops.
"""

from __future__ import annotations

import numba as nb
import numpy as np


def focal_from_fov(size_px: int, fov_rad: float) -> float:
    """Focal length (pixels) of an image ``size_px`` wide whose outer pixel edges span ``fov_rad`` radians.

    ``f = size / (2 tan(fov / 2))``: the edges ``-0.5`` and ``size - 0.5`` are at ``+-fov / 2``.
    """
    return size_px / (2.0 * np.tan(0.5 * fov_rad))


def pixel_grid(width: int, height: int):
    """Integer pixel centres ``u, v``: two ``(H, W)`` float64 arrays (column, row)."""
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    return u, v


def normalized_rays(u, v, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Rays with unit z, ``((u - cx) / fx, (v - cy) / fy, 1)``: ``(..., 3)`` float64, camera frame.

    A z-depth map times these gives camera-frame points (metres).
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    return np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(np.broadcast(u, v).shape)], axis=-1)


def unit_rays(u, v, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Unit rays of pixel coordinates ``u, v`` (continuous; integers are centres): ``(..., 3)`` float64."""
    d = normalized_rays(u, v, fx, fy, cx, cy)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def project(points_cam, fx: float, fy: float, cx: float, cy: float):
    """Continuous pixel coordinates of camera-frame points.

    Parameters
    ----------
    points_cam : (..., 3) float, metres, camera frame (OpenCV)

    Returns
    -------
    u, v : (...) float64, column / row (the centre of integer pixel (i, j) is (i, j)); NaN where z <= 0
    z : (...) float64, z-depth in metres (<= 0: behind the camera)
    """
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(z > 0, 1.0 / z, np.nan)
    return fx * p[..., 0] * inv + cx, fy * p[..., 1] * inv + cy, z


def radial_to_z(depth_radial, u, v, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """z-depth (metres) of radial depths ``depth_radial`` at pixel coordinates ``u, v``; 0 stays 0."""
    n = np.linalg.norm(normalized_rays(u, v, fx, fy, cx, cy), axis=-1)
    return np.asarray(depth_radial, dtype=np.float64) / n


def z_to_radial(depth_z, u, v, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Radial depth (metres, along the ray) of z-depths ``depth_z`` at pixel coordinates ``u, v``; 0 stays 0."""
    n = np.linalg.norm(normalized_rays(u, v, fx, fy, cx, cy), axis=-1)
    return np.asarray(depth_z, dtype=np.float64) * n


# --------------------------------------------------------------------------------------------------
# numba-callable helpers (compiled loops over pixels)
# --------------------------------------------------------------------------------------------------

@nb.njit(cache=True, inline="always")
def nb_pixel_ray(u, v, fx, fy, cx, cy):
    """Unit ray (x, y, z) of pixel coordinates ``u, v`` (float64); see :func:`unit_rays`."""
    x = (u - cx) / fx
    y = (v - cy) / fy
    n = np.sqrt(x * x + y * y + 1.0)
    return x / n, y / n, 1.0 / n


@nb.njit(cache=True, inline="always")
def nb_project(x, y, z, fx, fy, cx, cy):
    """Continuous pixel ``(u, v)`` of a camera-frame point with ``z > 0`` (the caller checks z)."""
    return fx * x / z + cx, fy * y / z + cy
