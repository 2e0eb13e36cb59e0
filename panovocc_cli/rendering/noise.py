"""Depth degradation of a real panoramic RGB-D rig (``--noise realistic``).

Applied to a clean radial depth map, in this order:

1. **Edge bleeding** ("flying pixels"): at a depth discontinuity (neighbour differs by more than
   ``EDGE_REL`` of the range) a pixel takes, with probability ``EDGE_P``, a random mix of its own and the
   neighbour's depth.
2. **Axial noise**: Gaussian with sigma ``SIGMA0 + SIGMA2 (r - 0.4)^2`` metres (the Kinect model of Nguyen,
   Izadi and Lovell, 3DIMPVT 2012), plus ``SIGMA_GRAZE`` theta^2 / (pi/2 - theta)^2 at incidence theta.
3. **Dropouts**: per pixel probability ``P0`` + ``P_POLE`` |sin latitude|^4 (stitching seams and lens
   fall-off toward the poles) + ``P_GRAZE`` ramp from 70 to 88 degrees incidence, plus blob holes
   (``BLOB_P`` of 8x8-pixel blocks, nearest-upsampled).
4. **Glass**: no depth (0) on the ``window`` class; structured light and ToF do not return from glass.
5. Readings beyond ``MAX_RANGE`` are dropped.

RGB gets mild Gaussian sensor noise (``RGB_SIGMA`` grey levels). Everything is drawn from
``np.random.default_rng([seed, frame])``, so a frame's noise does not depend on which frames are rendered.
"""

from __future__ import annotations

import numpy as np

from ..geometry.erp import latitudes

SIGMA0 = 0.0012  # metres
SIGMA2 = 0.0019  # metres per metre^2
SIGMA_GRAZE = 0.0001  # metres
P0 = 0.005
P_POLE = 0.15
P_GRAZE = 0.5
BLOB_P = 0.004
EDGE_REL = 0.05
EDGE_P = 0.5
MAX_RANGE = 10.0  # metres
RGB_SIGMA = 2.0  # grey levels

NOISE_PARAMS = {k: v for k, v in dict(globals()).items() if k.isupper()}


def degrade(depth: np.ndarray, rgb: np.ndarray, incidence: np.ndarray, glass: np.ndarray, seed: int,
            frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Degrade one clean ERP frame.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = no hit
    rgb : (H, W, 3) uint8
    incidence : (H, W) float, radians, ray/surface angle (0 = head on)
    glass : (H, W) bool, pixels on window glass
    seed, frame : the noise is drawn from ``np.random.default_rng([seed, frame])``

    Returns
    -------
    depth : (H, W) float32 metres (0 = no measurement); rgb : (H, W, 3) uint8
    """
    rng = np.random.default_rng([int(seed), int(frame)])
    H, W = depth.shape
    d = depth.astype(np.float64)
    valid = d > 0
    # 1. edge bleeding
    out = d.copy()
    for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
        nb = np.roll(d, shift, axis=axis)
        edge = valid & (nb > 0) & (np.abs(nb - d) > EDGE_REL * d)
        if axis == 0:  # rows do not wrap
            if shift == 1:
                edge[0] = False
            else:
                edge[-1] = False
        pick = edge & (rng.random((H, W)) < EDGE_P / 4)
        a = rng.random((H, W))
        out = np.where(pick, a * d + (1 - a) * nb, out)
    # 2. axial noise
    theta = np.clip(incidence, 0.0, np.pi / 2 - 0.05)
    sigma = SIGMA0 + SIGMA2 * (out - 0.4) ** 2 + SIGMA_GRAZE * theta ** 2 / (np.pi / 2 - theta) ** 2
    out = out + sigma * rng.standard_normal((H, W))
    # 3. dropouts
    lat = latitudes(H)
    p = P0 + P_POLE * np.abs(np.sin(lat))[:, None] ** 4 + P_GRAZE * np.clip(
        (np.degrees(incidence) - 70.0) / 18.0, 0.0, 1.0)
    drop = rng.random((H, W)) < p
    bh, bw = -(-H // 8), -(-W // 8)
    blobs = np.repeat(np.repeat(rng.random((bh, bw)) < BLOB_P, 8, axis=0), 8, axis=1)[:H, :W]
    drop |= blobs
    # 4./5. glass, range, invalid
    out = np.where(drop | glass | ~valid | (out <= 0) | (out > MAX_RANGE), 0.0, out)
    noisy_rgb = np.clip(rgb.astype(np.float32) + RGB_SIGMA * rng.standard_normal(rgb.shape).astype(np.float32),
                        0, 255)
    return out.astype(np.float32), np.round(noisy_rgb).astype(np.uint8)
