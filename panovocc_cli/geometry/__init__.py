"""Pure numpy maths of the shared conventions: ERP camera, voxel lattice, rigid poses."""
