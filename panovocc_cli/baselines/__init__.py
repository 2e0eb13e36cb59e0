"""Perspective baselines of the paper's comparison: the twelve-view split of panoramas (:mod:`.views`)."""
