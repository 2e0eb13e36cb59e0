"""The package's layers (../shared/STYLE.md, ARCHITECTURE.md), read from the code's own imports.

Each top-level part of ``panovocc_cli`` has a floor; a module may import from its own floor or below,
never from above, and no two parts import each other. No modules import each other in a loop, not even
through imports inside functions. Maths modules read no files and print nothing.
"""

import ast
from pathlib import Path

import pytest
from import_graph import PKG, circles, import_graph, imported_modules

# part -> floor (lower floors know nothing of higher ones)
FLOORS = {
    "errors": 0, "config": 0, "runtime": 0,
    "geometry": 1, "classes": 1,
    "grid": 2, "frame": 2,
    "io": 3,
    "datasets": 4, "semantics": 4, "evaluation": 4,
    "rendering": 5, "gt": 5, "gt_config": 5,
    "mapping": 6,
    "baselines": 7, "views": 7, "demo": 7, "slam": 7, "viz": 7, "mapquery": 7,
    "benchmark": 8,
    "cli": 9, "__main__": 10, "__init__": 10,
}

# the maths parts: their modules read no files and print nothing (no progress bars either) ...
MATHS_PARTS = ("mapping", "semantics", "geometry", "slam")
# ... but these, each for the reason given
RUNNERS = {
    "mapping/pipeline.py": "the map and revise run loops: read a sequence, write the map folder, progress bar",
    "mapping/mapper.py": "Mapper.save / Mapper.load: a map folder's config, memory and poses (io/mapstore.py)",
    "mapping/rpu.py": "the delta store: each frame's delta, the commit journal and snapshots go to the folder",
    "mapping/merge.py": "panovocc merge: reads the input map folders, writes the merged map folder, progress bar",
    "slam/run.py": "map --poses slam: writes trajectory.tum and slam.json beside the map",
}
FILE_CALLS = {"open", "print", "imread", "imwrite", "load", "save", "savez", "savez_compressed", "tqdm",
              "read_text", "write_text", "read_bytes", "write_bytes", "fromfile", "tofile"}


def _part(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imports(path):
    """(line, imported top-level part of panovocc_cli) of every import in ``path``."""
    for line, module in imported_modules(path):
        yield line, module.split(".")[0]


MODULES = sorted(p for p in PKG.rglob("*.py"))
MATHS = [p for p in MODULES if _part(p) in MATHS_PARTS and str(p.relative_to(PKG)) not in RUNNERS]


def _io_calls(path):
    """(line, name) of the calls and imports in ``path`` that read or write files or print."""
    tree = ast.parse(path.read_text(), str(path))
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
            if name in FILE_CALLS:
                bad.append((node.lineno, name))
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            mods = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
            if any(m.split(".")[0] in ("tqdm", "cv2") for m in mods):
                bad.append((node.lineno, mods[0]))
    return bad


def test_every_part_has_a_floor():
    missing = sorted({_part(p) for p in MODULES} - set(FLOORS))
    assert not missing, f"give these parts a floor in tests/test_layers.py: {missing}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PKG)))
def test_no_import_runs_up(path):
    own = FLOORS[_part(path)]
    up = [(line, t) for line, t in _imports(path) if t in FLOORS and FLOORS[t] > own]
    assert not up, f"{path.relative_to(PKG)} (floor {own}) imports from above: {up}"


def test_no_two_parts_import_each_other():
    edges = {(_part(p), t) for p in MODULES for _, t in _imports(p) if t != _part(p)}
    both = sorted((a, b) for a, b in edges if (b, a) in edges and a < b)
    assert not both, f"parts importing each other: {both}"


def test_no_modules_import_each_other_in_a_loop():
    """A loop of imports, even one closed by an import inside a function, means two modules each need the
    other: their definitions belong together, or the shared one below both."""
    loops = circles(import_graph())
    assert not loops, f"modules importing each other in a loop: {loops}"


def test_every_exemption_from_the_maths_rule_says_why_and_is_needed():
    for rel, why in RUNNERS.items():
        assert (PKG / rel).is_file(), f"RUNNERS names {rel}, which does not exist"
        assert _part(PKG / rel) in MATHS_PARTS and len(why.split()) >= 4, f"{rel}: say why it may do I/O"
        assert _io_calls(PKG / rel), f"{rel} does no I/O: take it out of RUNNERS"


@pytest.mark.parametrize("path", MATHS, ids=lambda p: str(p.relative_to(PKG)))
def test_maths_modules_read_no_files_and_print_nothing(path):
    bad = _io_calls(path)
    assert not bad, f"{path.relative_to(PKG)} does I/O or prints: {bad}"
