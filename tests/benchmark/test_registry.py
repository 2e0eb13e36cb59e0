"""The methods registry, the splits and the import-based availability checks."""

import dataclasses

import pytest

from panovocc_cli.benchmark.available import missing, unavailable_reason
from panovocc_cli.benchmark.methods import MAP_DEFAULTS, METHODS, map_cli_flags, select_methods
from panovocc_cli.benchmark.splits import SCALE_SPECS, SPLITS, select_splits
from panovocc_cli.errors import PanovoccError
from panovocc_cli.mapping.config import MapConfig


def test_missing_checks_modules_attributes_and_dataclass_fields():
    assert missing(["panovocc_cli.mapping", "panovocc_cli.mapping.config:MapConfig",
                    "panovocc_cli.mapping.config:MapConfig.semantic"]) == []
    lack = ["panovocc_cli.no_such_module", "panovocc_cli.mapping.config:NoSuch",
            "panovocc_cli.mapping.config:MapConfig.no_such_field"]
    assert missing(lack) == lack
    assert unavailable_reason([]) is None
    assert unavailable_reason(lack[:1]) == "not available in this build (needs panovocc_cli.no_such_module)"


def test_every_method_is_available_or_names_what_it_lacks():
    for m in METHODS.values():
        why = m.unavailable()
        assert why is None or why.startswith("not available in this build (needs "), (m.name, why)
        assert set(m.groups) <= {"main", "ablation", "upstream"} and m.groups
        if m.runner == "map":
            opts = m.map_options()
            assert set(opts) == set(MAP_DEFAULTS)
    # what exists on main now runs: PanOVOcc, w/o PSVF, w/o GSC, the segmenter variants
    for name in ("panovocc", "wo-psvf", "wo-gsc", "seg-exact", "seg-noisy", "seg-overconfident", "poses-true"):
        assert METHODS[name].unavailable() is None, name


def test_map_variants_are_real_map_options():
    fields = {f.name for f in dataclasses.fields(MapConfig)}
    assert "semantic" in fields and "geometry" in fields
    assert map_cli_flags(METHODS["wo-psvf"].map_options()) == ["--kernel", "point"]
    assert map_cli_flags(METHODS["wo-gsc"].map_options()) == ["--no-gsc"]
    assert map_cli_flags(METHODS["seg-exact"].map_options()) == ["--noise", "0"]
    assert map_cli_flags(METHODS["panovocc"].map_options()) == []


def test_selection_and_unknown_names():
    assert [m.name for m in select_methods("wo-gsc, panovocc")] == ["panovocc", "wo-gsc"]
    assert len(select_methods("all")) == len(METHODS)
    with pytest.raises(PanovoccError, match="unknown method 'nope'"):
        select_methods("panovocc,nope")
    assert [s.name for s in select_splits("all")] == list(SPLITS)
    with pytest.raises(PanovoccError, match="unknown split"):
        select_splits("replica")


def test_splits_scenes_are_fixed_and_nested_across_scales():
    rep = SPLITS["pan-replica-synth"]
    full = rep.scenes("full")
    assert len(full) >= 8 and {s.rooms for s in full} == {1, 2, 3}
    assert all(s.noise == "none" and not s.house for s in full)
    small = rep.scenes("small")
    assert [s.seed for s in small] == [s.seed for s in full[: len(small)]]
    holo = SPLITS["pan-holo-synth"]
    assert len(holo.scenes("full")) >= 5 and all(s.house and s.noise == "realistic" for s in holo.scenes("full"))
    assert holo.poses == "slam" and holo.gt == "lifted" and holo.classes == "eval12"
    assert set(SCALE_SPECS) == {"full", "small", "tiny"}


def test_baselines_use_the_splits_poses():
    """On a SLAM split the baselines map with the same (aligned) SLAM trajectory as PanOVOcc's row; on a
    true-pose split with the sequence's own poses."""
    from panovocc_cli.benchmark.sweep import build_sweep

    sw = build_sweep(select_splits("all"), select_methods("panovocc,persp-tsdf,single-pano"), "tiny")
    base = [t for t in sw.tasks if t.kind == "baseline"]
    maps = {t.label: t for t in sw.tasks if t.kind == "map"}
    assert base
    for t in base:
        if "pan-holo-synth" in t.label:
            slam = [d for d in t.deps if d.kind == "poses"]
            assert t.params["poses"] == "slam" and len(slam) == 1 and slam[0].params == {"source": "slam"}
            ours = [m for label, m in maps.items() if "pan-holo-synth" in label and "panovocc" in label]
            assert any(slam[0].key in [d.key for d in m.deps] for m in ours)  # the very same poses task
        else:
            assert "poses" not in t.params and [d.kind for d in t.deps] == ["render"]
