import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
