"""panovocc: panoramic open-vocabulary 3D semantic occupancy mapping and its benchmark.

Layers (see README "Architecture"):

* ``geometry``   pure numpy maths of the shared conventions (ERP camera, voxel lattice, poses).
* ``io``         one module per on-disk format, ``read_*`` / ``write_*`` pairs, atomic writes.
* ``datasets``   scene sources: the procedural generator and the Replica loader.
* ``rendering``  panoramic RGB-D rendering (Open3D ray casting, pyrender cube maps), sensor noise.
* ``gt``         mesh ground truth (ReplicaOcc protocol).
* ``mapping``    the mapper: PSVF kernel, reversible memory, free space, export.
* ``semantics``  segmenters and Geometry-Aware Semantic Consolidation.
* ``evaluation`` FreeOcc scoring, coverage curves, pictures.
* ``cli``        thin Typer commands, each building a config and calling one ``run_*`` function.
"""

import os as _os

# numba's parallel kernels: OpenMP first (libgomp, installed with open3d's Debian dependencies), never
# TBB first (the default order tries TBB and warns on every run when the installed TBB is too old).
_os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp workqueue tbb")
# OpenMP threads sleep at barriers instead of spinning (libgomp spins ~300k rounds by default). The
# machines this runs on have 2 cores shared with other jobs: a spinning worker competes with the
# thread it waits for, and the geometric update collapsed from ~10 to 66-130 ms/frame under load
# (load average ~3: `panovocc bench`, passive 16-17 ms vs spinning 66-128; Open3D 8-9 either way,
# it uses TBB, not this OpenMP runtime). Read when numba first loads libgomp, after this import.
_os.environ.setdefault("OMP_WAIT_POLICY", "passive")

__version__ = "0.1.0"
