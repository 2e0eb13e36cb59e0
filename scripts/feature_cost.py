"""What the feature memory costs per frame (issue 24), both arms in one process on the same frames.

For frames of a sequence (simulated segmenter, semantic stride ``--stride``), times, alternating the arms
frame by frame: the semantic update without features (``contributors.semantic_delta`` from the frame's
observation: what ``make bench``'s semantic pass measures) and with the observation's int8 features (D =
``--dim``), and, once per frame, the simulated segmenter's ``features`` (its embedding mode) and the
projection to int8 (``features.quantize_features``). Prints one JSON object of medians (ms) and ratios.

Usage: ``python scripts/feature_cost.py SEQ [--frames 10] [--stride 2] [--dim 64]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path


def main() -> None:
    import numpy as np

    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping.contributors import semantic_delta
    from panovocc_cli.mapping.params import GeometryParams
    from panovocc_cli.semantics.features import projection, quantize_features
    from panovocc_cli.semantics.observation import observe
    from panovocc_cli.semantics.params import EvidenceWeights
    from panovocc_cli.semantics.simulated import SimulatedConfig, SimulatedSegmenter, sequence_label_source

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--stride", type=int, default=2)
    ap.add_argument("--dim", type=int, default=64)
    a = ap.parse_args()
    seq = Sequence(a.seq)
    seg = SimulatedSegmenter(sequence_label_source(seq), SimulatedConfig())
    vocab = [n for n in seq.meta.class_names[1:]]
    w = dataclasses.replace(EvidenceWeights(), stride=a.stride)
    g = GeometryParams()
    s = a.stride
    t = {"update_ms": [], "update_features_ms": [], "segmenter_features_ms": [], "quantize_ms": []}
    for i in range(a.frames + 1):  # frame 0 warms the compiled kernels and loads the text model
        f = seq.frame(i)
        rgb = f.rgb[::s, ::s]
        obs = observe(seg.logits(rgb, vocab, frame_id=i))
        t0 = time.perf_counter()
        x = seg.features(rgb, frame_id=i)
        t1 = time.perf_counter()
        q = quantize_features(x, projection(x.shape[2], a.dim))
        t2 = time.perf_counter()
        fobs = dataclasses.replace(obs, features=q)
        rays = f.camera.rays()
        t3 = time.perf_counter()
        semantic_delta(f.depth, f.rgb, obs, f.T_world_cam, 0.08, w, g.min_range, g.max_range, rays)
        t4 = time.perf_counter()
        d = semantic_delta(f.depth, f.rgb, fobs, f.T_world_cam, 0.08, w, g.min_range, g.max_range, rays)
        t5 = time.perf_counter()
        assert d.channels["Z"].shape[1] == a.dim
        if i:
            for k, v in zip(t, (t4 - t3, t5 - t4, t1 - t0, t2 - t1)):
                t[k].append(1e3 * v)
    med = {k: round(float(np.median(v)), 1) for k, v in t.items()}
    med["update_ratio_features_over_none"] = round(med["update_features_ms"] / med["update_ms"], 2)
    med["frames"], med["stride"], med["dim"], med["size"] = a.frames, s, a.dim, list(seq.frame(0).depth.shape)
    print(json.dumps(med))


if __name__ == "__main__":
    main()
