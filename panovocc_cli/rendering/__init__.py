"""Panoramic rendering of scenes: ray casting, rasterisation (pyrender), sensor noise, the render stage."""
