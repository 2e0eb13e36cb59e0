"""Panoramic Signed Voxel Fusion (PSVF): one ERP frame's geometric evidence on the voxel lattice.

The method, one module per step (docs/mapping.md, "Per frame", gives the maths and the deviations):

* :mod:`.noise_fit` -- the radial noise fit: sigma_r(r) measured on the frame's own smooth surfaces;
* :mod:`.footprint` -- the footprint plane fit: each strided sample's depth from a plane through the
  pixels of its s x s footprint (averages ~s^2 readings on a plane);
* :mod:`.surfel` -- the surfel lift: samples to kernels on the observed surface (normal from the
  neighbouring samples, in-plane Gaussian = the ERP footprint carried onto the plane, thin along n);
* :mod:`.rays` -- the ray-aligned lift of the paper (extents ``box`` / ``centre``, the ``point`` ablation);
* :mod:`.splat` -- the splat kernels: support of each kernel in the voxels of the frame box;
* :mod:`.update` -- the per-frame update: lift, frame box, splat, free space (:mod:`..freespace`),
  the N rule and the extraction of the frame's sparse delta (:func:`.update.geometry_delta`).

ERP trigonometry (pixel angles, rays, local frames) comes from :mod:`panovocc_cli.geometry.erp`.
"""

from .noise_fit import radial_noise_fit
from .rays import lift_kernels, strided_pixels
from .splat import local_voxel, splat, splat_axis
from .surfel import lift_surfels, surfels_for
from .update import geometry_delta

__all__ = ["geometry_delta", "lift_kernels", "lift_surfels", "local_voxel", "radial_noise_fit", "splat", "splat_axis",
           "strided_pixels", "surfels_for"]
