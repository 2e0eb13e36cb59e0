"""Task keys (config + inputs + code), the cache, and resuming from it."""

import json

from panovocc_cli.benchmark.tasks import (Task, clean_stale, code_fingerprint, computed_events, execute, read_done,
                                          topological)


def test_key_changes_with_params_inputs_and_code():
    a = Task("synth", {"seed": 0, "rooms": 1, "frames": 4, "house": False}, code="c1")
    assert a == Task("synth", {"house": False, "frames": 4, "rooms": 1, "seed": 0}, code="c1")  # order-free
    assert a.key != Task("synth", {"seed": 1, "rooms": 1, "frames": 4, "house": False}, code="c1").key
    assert a.key != Task("synth", {"seed": 0, "rooms": 1, "frames": 4, "house": False}, code="c2").key
    r1 = Task("render", {"width": 128}, (a,), code="c1")
    b = Task("synth", {"seed": 9, "rooms": 1, "frames": 4, "house": False}, code="c1")
    assert r1.key != Task("render", {"width": 128}, (b,), code="c1").key  # an input's config is in the key
    order = topological([r1, Task("gt", {"source": "mesh"}, (a,), code="c1"), r1])
    assert [t.kind for t in order] == ["synth", "render", "gt"]


def test_code_fingerprint_is_stable_hex():
    assert code_fingerprint() == code_fingerprint() and len(code_fingerprint()) == 64


def test_code_fingerprint_covers_every_module_a_task_can_run():
    """Every module benchmark/tasks.py imports, directly or through others (imports inside functions
    included), is hashed into the fingerprint; the command line is not."""
    from import_graph import MODULES, import_graph, reachable

    from panovocc_cli.benchmark import tasks

    def hashed(module):
        rel = MODULES[module].relative_to(MODULES[""].parent).as_posix()
        return not rel.startswith(tasks._NOT_IN_FINGERPRINT) or rel in tasks._IN_FINGERPRINT

    run = reachable(import_graph(), "benchmark.tasks")
    assert {"mapping.pipeline", "evaluation.run", "rendering.render", "benchmark.methods"} <= run
    assert [m for m in sorted(run) if not hashed(m)] == []
    assert not hashed("cli.map_cmds") and not hashed("benchmark.bench") and hashed("mapping.mapper")


def test_execute_caches_and_resumes(tmp_path):
    cache = tmp_path / "cache"
    t = Task("synth", {"seed": 5, "rooms": 1, "frames": 3, "house": False}, label="synth x", code=code_fingerprint())
    stale = cache / "synth" / f".{t.short}.tmp.killed"  # what a worker killed mid-task leaves
    stale.mkdir(parents=True)
    (stale / "half-written").write_text("x")
    assert clean_stale(cache) == 1 and not stale.exists()
    r = execute(t.to_dict(), str(cache))
    assert r["status"] == "computed" and r["command"].startswith("panovocc synth synth/")
    folder = t.folder(cache)
    assert (folder / "scene" / "traj.txt").is_file() and read_done(cache, "synth", t.key)["key"] == t.key
    before = (folder / "task.json").stat().st_mtime_ns
    r2 = execute(t.to_dict(), str(cache))
    assert r2["status"] == "cached" and (folder / "task.json").stat().st_mtime_ns == before
    assert computed_events(cache) == {t.short: 1}
    assert json.loads((folder / "task.json").read_text())["params"]["seed"] == 5


def test_execute_refuses_other_code(tmp_path):
    import pytest

    from panovocc_cli.errors import PanovoccError

    t = Task("synth", {"seed": 5, "rooms": 1, "frames": 3, "house": False}, label="synth x", code="0" * 64)
    with pytest.raises(PanovoccError, match="other code"):
        execute(t.to_dict(), str(tmp_path))
    assert not (tmp_path / "synth").exists()


def test_a_second_runners_clean_keeps_a_live_runs_temporaries(tmp_path, monkeypatch):
    """Two sweeps share a cache: the second one's clean_stale (at its start) runs while the first computes a
    task in its temporary folder; that folder is live and stays, the task completes, and a killed run's
    leftover is still removed."""
    from panovocc_cli.benchmark import tasks

    cache = tmp_path / "cache"
    killed = cache / "synth" / ".0123456789abcdef.tmp.killed"
    killed.mkdir(parents=True)
    seen = {}

    def stage(p, out, deps, cache_):
        seen["removed"] = clean_stale(cache_)  # a second runner starting now
        (out / "scene.txt").write_text("done")
        return {"scene": "scene.txt"}, "panovocc synth", {}

    monkeypatch.setitem(tasks.STAGES, "synth", stage)
    t = Task("synth", {"seed": 1}, label="synth live", code="")
    r = execute(t.to_dict(), str(cache))
    assert r["status"] == "computed" and (t.folder(cache) / "scene.txt").read_text() == "done"
    assert seen["removed"] == 1 and not killed.exists()
    assert list((cache / "synth").glob(".*.tmp.*")) == []
