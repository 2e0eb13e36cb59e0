"""Defaults, seeds and tolerances, each defined once (STYLE.md "one documented place for tolerances").

Stage configs (``SynthConfig``, ``RenderConfig``, ``GtConfig``, ``MapConfig``, ...) take these as their
defaults and the command line shows them in ``--help``; nothing reads them as mutable globals. A module
that needs one imports it from here; no other module writes the number again.
"""

# --------------------------------------------------------------------------------------- defaults
DEFAULT_SEED = 0
"""Seed of every random choice (scene generator, render noise, simulated segmenter) unless given."""
DEFAULT_VOXEL_SIZE = 0.08
"""Voxel edge length h, metres: the paper's and ReplicaOcc/FreeOcc's resolution."""
DEFAULT_WIDTH = 1024
"""ERP width W in pixels (height = W / 2)."""
DEPTH_SCALE = 1000.0
"""uint16 depth PNG units per metre (millimetres)."""
MIN_WIDTH = 64
"""Pixels: the narrowest ERP image render, bench and demo accept (a 64 x 32 panorama, 5.6 degrees a pixel)."""
MAX_STRIDE = 64
"""Pixels: the largest kernel-lift stride map accepts (a larger one leaves nothing to map)."""
MAX_PICTURE_PX = 16384
"""Pixels: the widest picture show writes."""

# ------------------------------------------------------------------------------------- tolerances
RIGID_TOL = 1e-4
"""Largest |R Rᵀ − I| entry (and |last row − (0, 0, 0, 1)|) for a pose to count as rigid."""
LATTICE_TOL = 1e-4
"""Voxel units: how far ``origin / h − 0.5`` may be from whole numbers for a grid to lie on the lattice."""
VOXEL_SIZE_RTOL = 1e-6
"""Relative tolerance for two grids to have "the same voxel size"."""
GT_BOUNDARY_EPS = 1e-5
"""Voxel units: a mesh vertex this close below a voxel face counts as on it (float32 PLY coordinates)."""
SNAP_TOL = 0.25
"""Fraction of a voxel a ReplicaOcc voxel centre may be off the lattice and still be snapped onto it."""
COVERAGE_TOL_M = 0.01
"""Metres: a depth point this close to a voxel face also observes the voxel across it (coverage)."""
PROB_TOL = 1e-2
"""Precomputed segmenter probabilities: slack on [0, 1] and on their sum to 1."""
