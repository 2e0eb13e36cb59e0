"""The equirectangular (ERP) camera of CONVENTIONS.md.

Camera frame is OpenCV (x right, y down, z forward). Image width W = 2 H; pixel (u = column,
v = row) with centres at +0.5.

* longitude ``theta = (u + 0.5) * 2 pi / W - pi``; latitude ``phi = pi / 2 - (v + 0.5) * pi / H``
  (row 0 is the zenith);
* ray ``(cos phi sin theta, -sin phi, cos phi cos theta)``: the centre column looks along +z,
  moving right turns toward +x, column 0's left edge looks straight back;
* depth is radial: a point is ``ray * depth``.

The numba-callable helpers at the end (:func:`trig_tables`, :func:`cam_frame`, :func:`cam_point`,
:func:`cam_pixel`) are the same formulas for compiled per-pixel loops (the mapper's kernel lift, noise
fit and free-space test): one place where the ERP trigonometry is written.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import PanovoccError


def check_erp_size(width: int, height: int | None = None) -> tuple[int, int]:
    """Validate an ERP size and return ``(W, H)``; W must be even and W = 2 H."""
    if width <= 0 or width % 2:
        raise PanovoccError(f"ERP width must be a positive even number (W = 2 H), got {width}")
    h = width // 2 if height is None else height
    if 2 * h != width:
        raise PanovoccError(f"ERP size {width}x{h} is not 2:1 (expected width = 2 x height)")
    return width, h


def pixel_to_angles(u, v, width: int, height: int):
    """Longitude and latitude (radians) of pixel coordinates.

    Parameters
    ----------
    u, v : array_like float
        Column and row; integer values are pixel corners, ``+0.5`` pixel centres are added here,
        so pass integer indices for centres.
    """
    theta = (np.asarray(u, dtype=np.float64) + 0.5) * (2.0 * np.pi / width) - np.pi
    phi = np.pi / 2.0 - (np.asarray(v, dtype=np.float64) + 0.5) * (np.pi / height)
    return theta, phi


def angles_to_ray(theta, phi) -> np.ndarray:
    """Unit rays ``(..., 3)`` float64 in the camera frame from longitude/latitude (radians)."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    cp = np.cos(phi)
    return np.stack([cp * np.sin(theta), -np.sin(phi), cp * np.cos(theta)], axis=-1)


def ray_directions(width: int, height: int | None = None, dtype=np.float64) -> np.ndarray:
    """Unit ray of every pixel centre.

    Returns
    -------
    rays : (H, W, 3) ``dtype``, camera frame (OpenCV)
    """
    width, height = check_erp_size(width, height)
    u = np.arange(width)
    v = np.arange(height)
    theta, phi = pixel_to_angles(u[None, :], v[:, None], width, height)
    return angles_to_ray(np.broadcast_to(theta, (height, width)), np.broadcast_to(phi, (height, width))).astype(
        dtype, copy=False
    )


def latitudes(height: int) -> np.ndarray:
    """Latitude (radians) of each row centre, ``(H,)`` float64, +pi/2 at the top."""
    return np.pi / 2.0 - (np.arange(height) + 0.5) * (np.pi / height)


def points_to_angles(points_cam):
    """Longitude, latitude and range of camera-frame points ``(..., 3)``."""
    p = np.asarray(points_cam, dtype=np.float64)
    r = np.linalg.norm(p, axis=-1)
    theta = np.arctan2(p[..., 0], p[..., 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = -np.arcsin(np.clip(p[..., 1] / np.where(r > 0, r, 1.0), -1.0, 1.0))
    return theta, phi, r


def project(points_cam, width: int, height: int):
    """Continuous pixel coordinates of camera-frame points (the inverse of :func:`ray_directions`).

    Returns
    -------
    u, v : (...) float64
        Continuous column/row such that the pixel centre of integer pixel ``(i, j)`` is ``(i, j)``:
        ``u = (theta + pi) W / (2 pi) - 0.5``, ``v = (pi / 2 - phi) H / pi - 0.5``.
    r : (...) float64, range (metres, radial)
    """
    theta, phi, r = points_to_angles(points_cam)
    u = (theta + np.pi) * width / (2.0 * np.pi) - 0.5
    v = (np.pi / 2.0 - phi) * height / np.pi - 0.5
    return u, v, r


def project_to_pixel(points_cam, width: int, height: int):
    """Integer pixel ``(row, col)`` containing each camera-frame point, plus its range.

    Column wraps around (longitude is periodic); row is clipped to the image.

    Returns
    -------
    row, col : (...) int64
    r : (...) float64, metres
    """
    u, v, r = project(points_cam, width, height)
    col = np.floor(u + 0.5).astype(np.int64) % width
    row = np.clip(np.floor(v + 0.5).astype(np.int64), 0, height - 1)
    return row, col, r


def backproject(depth: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
    """Camera-frame points of a radial depth map.

    Parameters
    ----------
    depth : (H, W) float, metres, radial, 0 = invalid
    rays : (H, W, 3) float, optional precomputed :func:`ray_directions`

    Returns
    -------
    points_cam : (H, W, 3) float64 (invalid pixels give the origin)
    """
    h, w = depth.shape
    if rays is None:
        rays = ray_directions(w, h)
    return rays * np.asarray(depth, dtype=np.float64)[..., None]


def local_frames(theta, phi) -> np.ndarray:
    """Orthonormal (longitude, latitude, ray) directions of each measurement, camera frame.

    Returns
    -------
    E : (..., 3, 3) float64 whose columns are ``e_theta`` (increasing longitude), ``e_phi``
        (increasing latitude, toward the zenith) and ``e_r`` (the ray).
    """
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    e_r = np.stack([cp * st, -sp, cp * ct], axis=-1)
    e_t = np.stack([ct, np.zeros_like(theta), -st], axis=-1)
    e_p = np.stack([-sp * st, -cp, -sp * ct], axis=-1)
    return np.stack([e_t, e_p, e_r], axis=-1)


# --------------------------------------------------------------------------------------------------
# numba-callable helpers (compiled loops over pixels)
# --------------------------------------------------------------------------------------------------

@nb.njit(cache=True)
def trig_tables(H, W):
    """sin / cos of every ERP row's latitude and every column's longitude (pixel centres).

    Returns
    -------
    sphi, cphi : (H,) float64, sin / cos of ``phi = pi / 2 - (v + 0.5) pi / H``
    sth, cth : (W,) float64, sin / cos of ``theta = (u + 0.5) 2 pi / W - pi``
    """
    dth = 2.0 * np.pi / W
    dph = np.pi / H
    sphi, cphi = np.empty(H), np.empty(H)
    for vv in range(H):
        ph = 0.5 * np.pi - (vv + 0.5) * dph
        sphi[vv], cphi[vv] = np.sin(ph), np.cos(ph)
    sth, cth = np.empty(W), np.empty(W)
    for uu in range(W):
        th = (uu + 0.5) * dth - np.pi
        sth[uu], cth[uu] = np.sin(th), np.cos(th)
    return sphi, cphi, sth, cth


@nb.njit(cache=True, inline="always")
def cam_frame(sp, cp, st, ct, Ec):
    """Fill ``Ec`` ((3, 3) float64) with the camera-frame columns e_theta, e_phi, e_ray of the pixel of
    latitude sin / cos ``sp``, ``cp`` and longitude sin / cos ``st``, ``ct`` (:func:`local_frames`)."""
    Ec[0, 0], Ec[1, 0], Ec[2, 0] = ct, 0.0, -st
    Ec[0, 1], Ec[1, 1], Ec[2, 1] = -sp * st, -cp, -sp * ct
    Ec[0, 2], Ec[1, 2], Ec[2, 2] = cp * st, -sp, cp * ct


@nb.njit(cache=True, inline="always")
def cam_point(r, sp, cp, st, ct):
    """Camera-frame point (x, y, z) metres at radial depth ``r`` metres along the pixel's ray."""
    return r * cp * st, -r * sp, r * cp * ct


@nb.njit(cache=True, inline="always", error_model="numpy")
def poly_atan2(y, x):
    """atan2 by a minimax polynomial (|error| < 1e-5 rad, 1/600 of a pixel at 1024 wide); deterministic.

    Written with selects, no branches, so that loops calling it vectorise (same values either way)."""
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    a = min(ax, ay) / mx  # NaN when x = y = 0, replaced below
    s = a * a
    r = ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a + 0.99997726 * a
    r = 0.5 * np.pi - r if ay > ax else r
    r = np.pi - r if x < 0.0 else r
    r = -r if y < 0.0 else r
    return 0.0 if mx == 0.0 else r


@nb.njit(cache=True, inline="always", error_model="numpy")
def cam_pixel(px, py, pz, H, W):
    """Range (metres) and containing ERP pixel (row, col) of the camera-frame point ``(px, py, pz)`` in an
    ``H`` x ``W`` image: :func:`project_to_pixel`'s, the angles by :func:`poly_atan2` (so a point within
    about 1e-5 rad of a pixel border may fall on its other side); the column wraps, the row is clipped. Branch-free, so that loops calling it vectorise (the free-space test)."""
    r = np.sqrt(px * px + py * py + pz * pz)
    theta = poly_atan2(px, pz)
    phi = poly_atan2(-py, np.sqrt(px * px + pz * pz))
    col = int(np.floor((theta + np.pi) * W / (2.0 * np.pi)))  # in [0, W] since theta is in [-pi, pi]
    col = col - W if col >= W else col
    col = col + W if col < 0 else col
    row = int(np.floor((0.5 * np.pi - phi) * H / np.pi))
    row = 0 if row < 0 else row
    row = H - 1 if row >= H else row
    return r, row, col
