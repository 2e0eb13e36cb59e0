"""The toolkit's benchmark: embedded splits, the task graph of a sweep, its Dask runner, paper-shaped tables.

* :mod:`.splits`    the embedded splits (``pan-replica-synth``, ``pan-holo-synth``) from fixed seeds, at
                    three scales (``full``, ``small``, ``tiny``);
* :mod:`.methods`   the methods registry: PanOVOcc, its ablations, the baselines and the upstream variants,
                    each available or not in this build (checked by import, never faked);
* :mod:`.tasks`     one task per stage and scene (synth, gt, render, poses, map, eval, coverage, show),
                    keyed by a hash of its config, its inputs' keys and the code; idempotent, cached;
* :mod:`.runner`    executes a task graph on Dask distributed (a local cluster, or one by address) or in
                    process, resuming from the cache;
* :mod:`.tables`    rows of the main, ablation, upstream and coverage tables, with the paper's published
                    rows (:mod:`.reported`) marked ``reported``;
* :mod:`.run`       ``run_reproduce``: the whole sweep and the files in ``results/``.

Libraries here print nothing except :mod:`.runner` (progress) and :mod:`.run` (files, summary).
"""

import sys


def panovocc_command(*args) -> list:
    """The argv that runs ``panovocc ARGS...`` in a process of its own with this interpreter (the benchmarks
    time and run the commands as a user does)."""
    return [sys.executable, "-m", "panovocc_cli", *map(str, args)]
