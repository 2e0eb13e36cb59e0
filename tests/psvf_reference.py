"""Numpy transcriptions of the ray-aligned PSVF kernel (the reference the compiled lift is tested
against: panovocc_cli/mapping/psvf/rays.py)."""

import numpy as np

from panovocc_cli.geometry.erp import local_frames, pixel_to_angles
from panovocc_cli.mapping.psvf.rays import SIGMA_MIN, strided_pixels

def measurement_weight(phi, r, w_pole: float, r_half: float) -> np.ndarray:
    """``w_lat(phi) * w_range(r)`` (float64), phi radians latitude, r metres (see module docstring)."""
    phi = np.asarray(phi, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    return (1.0 - (1.0 - w_pole) * np.sin(phi) ** 2) / (1.0 + r / r_half)



def kernel_params(depth: np.ndarray, T_world_cam: np.ndarray, stride: int, alpha: float, beta: float,
                  min_range: float, max_range: float):
    """Lift the strided valid pixels of an ERP depth map and build their kernels.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid
    T_world_cam : (4, 4) float64
    stride : int, pixels

    Returns
    -------
    x_world : (n, 3) float64, metres, world frame
    E_world : (n, 3, 3) float64, columns = longitude, latitude, ray directions (world)
    sigma : (n, 3) float64, metres, kernel scales along those axes
    phi : (n,) float64 radians, r : (n,) float64 metres
    """
    H, W = depth.shape
    rows, cols = strided_pixels(W, H, stride)
    d = depth[np.ix_(rows, cols)].astype(np.float64)
    valid = (d > 0) & (d >= min_range) & (d <= max_range)
    vi, ui = np.nonzero(valid)
    r = d[vi, ui]
    theta, phi = pixel_to_angles(cols[ui], rows[vi], W, H)
    E_cam = local_frames(theta, phi)
    R = T_world_cam[:3, :3]
    E_world = np.einsum("ij,njk->nik", R, E_cam)
    x_world = r[:, None] * E_world[:, :, 2] + T_world_cam[:3, 3]
    dth = 2.0 * np.pi * stride / W
    dph = np.pi * stride / H
    sigma = np.stack([r * np.abs(np.cos(phi)) * dth, r * dph, alpha * r + beta], axis=-1)
    sigma = np.maximum(sigma, SIGMA_MIN)
    return x_world, E_world, sigma, phi, r



def kernel_inverse_cov(E_world: np.ndarray, sigma: np.ndarray):
    """Inverse covariances and bounding half-extents of the kernels.

    Returns
    -------
    P : (n, 3, 3) float64, ``Sigma^-1 = E diag(1 / sigma^2) E^T``, 1/m^2
    half : (n, 3) float64, metres, ``sqrt(diag Sigma)``; the d^2 <= kappa^2 ellipsoid lies within
        ``x +- kappa * half`` on each world axis
    """
    P = np.einsum("nik,nk,njk->nij", E_world, 1.0 / sigma ** 2, E_world)
    half = np.sqrt(np.einsum("nik,nk->ni", E_world ** 2, sigma ** 2))
    return P, half
