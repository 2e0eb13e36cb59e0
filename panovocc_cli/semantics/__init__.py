"""Semantic side of the mapper: segmenters, per-frame semantic evidence and GSC consolidation.

* :mod:`.segmenter` — the :class:`Segmenter` interface (no ground truth in the call);
* :mod:`.registry` — :func:`build_segmenter`, segmenters by name;
* :mod:`.simulated` — the seeded ground-truth-based open-vocabulary segmenter (the default);
* :mod:`.precomputed` — scores another model wrote (``precomputed:DIR``), with :func:`write_precomputed`;
* :mod:`.clip` — the training-free dense CLIP segmenter (NACLIP's recipe on open_clip; extra ``.[clip]``);
* :mod:`.tiling` — any perspective segmenter on panoramas through overlapping pinhole tiles;
* :mod:`.query` — free-text queries of a finished map (text -> classes -> voxels, clusters) and re-labelling;
* :mod:`.observation` — a frame's segmenter output reduced to what the map keeps (top-2 classes);
* :mod:`.evidence` — weights eta and the compiled per-frame sparse semantic delta;
* :mod:`.gsc` — Geometry-Aware Semantic Consolidation and the bounded nearest-evidence transfer;
* :mod:`.metrics2d` — per-frame 2D scores of a segmentation against ground truth (pure).
"""
