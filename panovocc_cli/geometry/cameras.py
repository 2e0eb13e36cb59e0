"""Camera models: how a frame's pixels map to rays in the camera frame (OpenCV axes, CONVENTIONS.md).

Only the equirectangular camera exists today (:class:`ErpCamera`); pinhole cameras and rigs of views
will sit beside it. A camera is a small immutable value: frames carry one, the mapper asks it for the
image size and the unit ray of every pixel.
"""

from __future__ import annotations

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
