"""Camera models: how a frame's pixels map to rays in the camera frame (OpenCV axes, CONVENTIONS.md).

:class:`ErpCamera` (panoramas), :class:`PinholeCamera` (perspective views) and :class:`ViewRig` (pinhole
views attached to a panorama: the twelve-view rig of the paper's baselines, cube faces). A camera is a
small immutable value: frames carry one, the mapper asks it for the image size and the unit ray of
every pixel; each also projects points to pixels and converts radial <-> its own depth convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import PanovoccError


@dataclass(frozen=True)
class ErpCamera:
    """An equirectangular (ERP) panorama of ``width`` x ``height`` pixels, ``width = 2 height``.

    Longitude and latitude of pixel centres, rays and the radial depth convention:
    :mod:`panovocc_cli.geometry.erp` (CONVENTIONS.md, "Equirectangular (ERP) camera").
    """

    width: int
    height: int

    model = "erp"

    def __post_init__(self):
        w, h = self.width, self.height
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (w, h)):
            raise PanovoccError(f"ERP camera size must be integers, got {w!r} x {h!r}")
        if w <= 0 or w % 2 or 2 * h != w:
            raise PanovoccError(f"ERP size {w}x{h} is not 2:1 with a positive even width")
        object.__setattr__(self, "width", int(w))
        object.__setattr__(self, "height", int(h))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(H, W)`` in pixels."""
        return (self.height, self.width)

    def rays(self, dtype=np.float64) -> np.ndarray:
        """Unit ray of every pixel centre: ``(H, W, 3)`` ``dtype``, camera frame (OpenCV)."""
        from .erp import ray_directions

        return ray_directions(self.width, self.height, dtype)

    def project(self, points_cam):
        """Continuous pixel ``(u, v)`` (centre of pixel (i, j) at (i, j)) and radial depth of camera-frame
        points ``(..., 3)`` metres: three ``(...)`` float64 arrays (:func:`geometry.erp.project`)."""
        from .erp import project

        return project(points_cam, self.width, self.height)


def _check_size(w, h, what: str) -> tuple[int, int]:
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (w, h)):
        raise PanovoccError(f"{what} size must be integers, got {w!r} x {h!r}")
    if w <= 0 or h <= 0:
        raise PanovoccError(f"{what} size {w}x{h} must be positive")
    return int(w), int(h)


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera: focal lengths ``fx, fy`` and principal point ``cx, cy`` in pixels, image
    ``width`` x ``height``. OpenCV axes and pixel centres (the centre of pixel (i, j) is (i, j));
    depth is z-depth. Formulas: :mod:`panovocc_cli.geometry.pinhole`.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    model = "pinhole"

    def __post_init__(self):
        w, h = _check_size(self.width, self.height, "pinhole camera")
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        for k in ("fx", "fy", "cx", "cy"):
            v = float(getattr(self, k))
            if not math.isfinite(v) or (k in ("fx", "fy") and v <= 0):
                raise PanovoccError(f"pinhole {k} = {getattr(self, k)!r}; expected a finite number"
                                    + (" > 0" if k in ("fx", "fy") else ""))
            object.__setattr__(self, k, v)

    @classmethod
    def from_fov(cls, width: int, height: int, fov_rad: float) -> "PinholeCamera":
        """Square pixels, centred principal point ``((W - 1) / 2, (H - 1) / 2)``, horizontal field of view
        ``fov_rad`` radians between the outer pixel edges (``fx = W / (2 tan(fov / 2))``)."""
        from .pinhole import focal_from_fov

        if not 0.0 < fov_rad < math.pi:
            raise PanovoccError(f"pinhole field of view {math.degrees(fov_rad):g} deg; expected in (0, 180)")
        w, h = _check_size(width, height, "pinhole camera")
        f = focal_from_fov(w, fov_rad)
        return cls(f, f, (w - 1) / 2.0, (h - 1) / 2.0, w, h)

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(H, W)`` in pixels."""
        return (self.height, self.width)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix ``(3, 3)`` float64 (OpenCV)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def intrinsics(self) -> dict:
        """``{"fx", "fy", "cx", "cy"}`` floats (the keys of a pinhole sequence's meta.json)."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}

    def pixel_rays(self, u, v, dtype=np.float64) -> np.ndarray:
        """Unit rays ``(..., 3)`` of pixel coordinates ``u, v`` (continuous; integers are centres)."""
        from .pinhole import unit_rays

        return unit_rays(u, v, self.fx, self.fy, self.cx, self.cy).astype(dtype, copy=False)

    def rays(self, dtype=np.float64) -> np.ndarray:
        """Unit ray of every pixel centre: ``(H, W, 3)`` ``dtype``, camera frame (OpenCV)."""
        from .pinhole import pixel_grid

        return self.pixel_rays(*pixel_grid(self.width, self.height), dtype=dtype)

    def project(self, points_cam):
        """Continuous pixel ``(u, v)`` and z-depth of camera-frame points ``(..., 3)`` metres: three ``(...)``
        float64 arrays; ``u, v`` are NaN behind the camera (z <= 0)."""
        from .pinhole import project

        return project(points_cam, self.fx, self.fy, self.cx, self.cy)

    def radial_to_z(self, depth_radial: np.ndarray) -> np.ndarray:
        """z-depth ``(H, W)`` float64 metres of a radial depth image ``(H, W)`` (0 = invalid stays 0)."""
        from .pinhole import pixel_grid, radial_to_z

        return radial_to_z(depth_radial, *pixel_grid(self.width, self.height), self.fx, self.fy, self.cx, self.cy)

    def z_to_radial(self, depth_z: np.ndarray) -> np.ndarray:
        """Radial depth ``(H, W)`` float64 metres of a z-depth image ``(H, W)`` (0 = invalid stays 0)."""
        from .pinhole import pixel_grid, z_to_radial

        return z_to_radial(depth_z, *pixel_grid(self.width, self.height), self.fx, self.fy, self.cx, self.cy)

    def backproject(self, depth_z: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(H, W, 3)`` float64 metres of a z-depth image (invalid pixels: the origin)."""
        from .pinhole import normalized_rays, pixel_grid

        d = normalized_rays(*pixel_grid(self.width, self.height), self.fx, self.fy, self.cx, self.cy)
        return d * np.asarray(depth_z, dtype=np.float64)[..., None]


def view_rotation(azimuth_rad: float, pitch_rad: float) -> np.ndarray:
    """``R_cam_view`` (3, 3) float64: the axes of a view (OpenCV) in its panorama's camera frame (OpenCV).

    The view looks along the panorama's ray of longitude ``azimuth`` and latitude ``pitch``
    (CONVENTIONS.md: azimuth 0 is the panorama's centre column, +z; 90 deg turns right, toward +x;
    positive pitch looks up, toward -y), with no roll: its x axis stays horizontal in the camera frame.
    Columns: view x (right) = e_theta, view z (forward) = the ray, view y (down) = z cross x.
    """
    sa, ca = math.sin(azimuth_rad), math.cos(azimuth_rad)
    sp, cp = math.sin(pitch_rad), math.cos(pitch_rad)
    z = np.array([cp * sa, -sp, cp * ca])
    x = np.array([ca, 0.0, -sa])
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


@dataclass(frozen=True)
class RigView:
    """One pinhole view of a :class:`ViewRig`: ``name``, its camera, its direction (``azimuth_rad``,
    ``pitch_rad``, see :func:`view_rotation`) and ``R_cam_view`` (3, 3) float64."""

    name: str
    camera: PinholeCamera
    azimuth_rad: float
    pitch_rad: float
    R_cam_view: np.ndarray

    @property
    def T_cam_view(self) -> np.ndarray:
        """``(4, 4)`` float64 view-to-panorama-camera transform (pure rotation, shared centre)."""
        T = np.eye(4)
        T[:3, :3] = self.R_cam_view
        return T

    def T_world_view(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Pose of the view ``(..., 4, 4)`` float64: ``T_world_cam @ T_cam_view``."""
        return np.asarray(T_world_cam, dtype=np.float64) @ self.T_cam_view


#: Elevations of the twelve-view rig: (suffix, sign of the pitch), in the order views are numbered.
TWELVE_ELEVATIONS = (("up", 1), ("mid", 0), ("down", -1))
#: Azimuths of the twelve-view rig, degrees (0 = the panorama's centre column, 90 = to its right).
TWELVE_AZIMUTHS_DEG = (0, 90, 180, 270)
#: Default pitch of the upper and lower rows of the twelve-view rig, degrees (docs/views.md).
TWELVE_PITCH_DEG = 45.0


@dataclass(frozen=True)
class ViewRig:
    """Pinhole views sharing the centre of a panorama (its camera frame), each rotated by ``R_cam_view``.

    Build one with :meth:`twelve` (four azimuths x three elevations, the paper's perspective baselines)
    or :meth:`cube` (six 90-degree faces).
    """

    views: tuple[RigView, ...]

    def __len__(self) -> int:
        return len(self.views)

    def __iter__(self):
        return iter(self.views)

    def __getitem__(self, i) -> RigView:
        return self.views[i]

    @property
    def names(self) -> list[str]:
        return [v.name for v in self.views]

    @classmethod
    def twelve(cls, size: int, fov_rad: float = math.pi / 2, pitch_rad: float = math.radians(TWELVE_PITCH_DEG)
               ) -> "ViewRig":
        """Twelve square ``size`` x ``size`` views of horizontal and vertical field of view ``fov_rad``: azimuths
        0, 90, 180, 270 deg at pitches ``+pitch`` (up), 0 (mid), ``-pitch`` (down). Numbered up row first,
        then mid, then down, each row by azimuth; named ``view_NN_azAAA_EL`` (``view_00_az000_up``)."""
        if not 0.0 <= pitch_rad <= math.pi / 2:
            raise PanovoccError(f"view pitch {math.degrees(pitch_rad):g} deg; expected in [0, 90]")
        cam = PinholeCamera.from_fov(size, size, fov_rad)
        views = []
        for el, sign in TWELVE_ELEVATIONS:
            for az in TWELVE_AZIMUTHS_DEG:
                a, p = math.radians(az), sign * pitch_rad
                views.append(RigView(f"view_{len(views):02d}_az{az:03d}_{el}", cam, a, p, view_rotation(a, p)))
        return cls(tuple(views))

    @classmethod
    def cube(cls, size: int) -> "ViewRig":
        """Six ``size`` x ``size`` 90-degree cube faces: front (+z), right (+x), back, left, up (-y), down (+y)."""
        cam = PinholeCamera.from_fov(size, size, math.pi / 2)
        dirs = (("front", 0, 0), ("right", 90, 0), ("back", 180, 0), ("left", 270, 0), ("up", 0, 90),
                ("down", 0, -90))
        # axis-aligned faces: entries exactly 0 or +-1 (sin(pi) would leave 1.2e-16)
        return cls(tuple(RigView(n, cam, math.radians(a), math.radians(p),
                                 np.round(view_rotation(math.radians(a), math.radians(p))) + 0.0)
                         for n, a, p in dirs))
