"""The Rerun view of a map (``panovocc view``) and the live log of a mapping run (``map --rerun``).

:mod:`.rerun_log` turns the toolkit's data (grids, poses, panoramas, depth) into Rerun archetypes under
one entity layout; :mod:`.view` logs a finished map folder; :mod:`.live` is the observer ``run_map`` calls
per frame. ``rerun-sdk`` is an optional extra (``pip install 'panovocc[viz]'``; ``make setup`` installs it).
"""
