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

Importing the package has no side effects. The process settings the kernels want (OpenMP threads that
sleep at barriers, glibc keeping freed heap) are applied by :func:`panovocc_cli.runtime.setup`, which
the command line calls and a library user calls once before mapping or rendering.
"""

__version__ = "0.1.0"
