"""Seeds and tolerances in one place. Stage configs take these as defaults; nothing reads globals."""

DEFAULT_SEED = 0
DEFAULT_VOXEL_SIZE = 0.08  # metres, the paper's resolution
DEFAULT_WIDTH = 1024  # ERP width in pixels (height = width / 2)
DEPTH_SCALE = 1000.0  # uint16 depth PNG units per metre (millimetres)
RIGID_TOL = 1e-4  # max |R R^T - I| entry for a pose to count as rigid

MIN_WIDTH = 64  # pixels: the narrowest ERP image render and demo accept
MAX_STRIDE = 64  # pixels: the largest kernel-lift stride map accepts (a larger one leaves nothing to map)
MAX_PICTURE_PX = 16384  # pixels: the widest picture show writes
