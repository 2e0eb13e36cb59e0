"""The paper's published numbers (../shared/paper/panovocc-paper.tex), shown beside ours as ``reported``.

Transcribed from the paper's tables (labels below); tests/benchmark/test_reproduce.py checks every number
against the TeX source when the paper is present. They were measured on Pan-Replica and Pan-Holo360D
(real Replica scenes and real Holo360D captures), not on the embedded synthetic splits: they are shown
for reference, never mixed into our measurements.
"""

from __future__ import annotations

EVAL8_COLUMNS = ("ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table")
OPEN4_COLUMNS = ("curtain", "door", "tv", "lighting")

# tab:panreplica_main — Method: (IoU, mIoU, ceiling, floor, wall, window, chair, bed, sofa, table)
MAIN_REPLICA = {
    "EmbodiedOcc": (18.02, 5.58, 3.19, 6.34, 10.05, 3.44, 4.26, 7.78, 6.81, 2.76),
    "EmbodiedOcc++": (19.41, 5.96, 3.04, 7.89, 10.61, 4.26, 4.31, 6.34, 7.06, 4.18),
    "VEOcc": (20.83, 17.02, 19.08, 12.42, 13.83, 7.96, 21.26, 8.96, 34.29, 18.41),
    "GPOcc": (19.64, 15.72, 21.14, 19.98, 9.75, 7.22, 14.53, 10.96, 29.87, 12.30),
    "FreeOcc (RGBD)": (55.60, 29.93, 39.57, 41.83, 39.77, 20.55, 17.43, 29.81, 38.05, 12.45),
    "PanOVOcc": (75.63, 36.99, 54.79, 57.26, 58.47, 23.93, 16.04, 17.30, 45.25, 22.87),
}

# tab:panholo360d_main — Method: (IoU, mIoU(8), 8 classes, curtain, door, tv, lighting); None = not reported
MAIN_HOLO = {
    "EmbodiedOcc": (18.21, 5.16, 0.15, 13.35, 9.65, 4.10, 3.08, 4.30, 3.12, 3.49, None, None, None, None),
    "EmbodiedOcc++": (18.02, 4.99, 0.16, 13.21, 10.15, 3.07, 2.81, 3.81, 2.95, 3.74, None, None, None, None),
    "VEOcc": (23.01, 12.49, 15.64, 7.81, 18.72, 13.41, 11.47, 4.10, 15.85, 12.89, None, None, None, None),
    "GPOcc": (22.03, 14.56, 29.20, 11.15, 17.24, 12.88, 8.54, 8.20, 21.51, 7.76, None, None, None, None),
    "FreeOcc (RGBD)": (20.66, 10.01, 13.13, 13.38, 12.17, 7.76, 4.89, 11.37, 11.74, 5.62, 13.47, 3.11, 6.40, 8.21),
    "PanOVOcc": (66.27, 34.72, 67.17, 49.61, 42.33, 20.03, 12.52, 29.40, 42.93, 13.80, 50.33, 20.65, 31.04, 18.81),
}

# tab:component_ablation (Pan-Replica) — Variant: (IoU, mIoU)
ABLATION = {
    "w/o PSVF": (53.02, 23.51),
    "w/o GSC": (76.75, 31.51),
    "w/o RPU": (69.69, 30.54),
    "Full model": (76.75, 32.09),
}

# tab:perception_ablation — Row: (Pan-Replica IoU, mIoU, Pan-Holo360D IoU, mIoU)
UPSTREAM = {
    "ours (ODGS-SLAM + OOOPS)": (77.88, 33.54, 65.64, 33.71),
    "OpenVSLAM": (60.25, 27.15, 58.35, 29.35),
    "OpenVSLAM dense": (62.29, 27.65, 41.67, 20.39),
    "GT poses": (77.77, 34.16, 65.86, 32.60),
    "CAT-Seg": (77.88, 38.20, 65.64, 32.79),
    "NACLIP": (77.88, 29.32, 65.64, 31.82),
}

TABLE_LABELS = {"main:pan-replica-synth": "tab:panreplica_main", "main:pan-holo-synth": "tab:panholo360d_main",
                "ablation": "tab:component_ablation", "upstream": "tab:perception_ablation"}
