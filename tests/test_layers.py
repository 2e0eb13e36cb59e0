"""The package's layers (../shared/STYLE.md, ARCHITECTURE.md), read from the code's own imports.

Each top-level part of ``panovocc_cli`` has a floor; a module may import from its own floor or below,
never from above, and no two parts import each other. Maths modules read no files and print nothing.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "panovocc_cli"

# part -> floor (lower floors know nothing of higher ones)
FLOORS = {
    "errors": 0, "config": 0, "runtime": 0,
    "geometry": 1, "classes": 1,
    "grid": 2, "frame": 2,
    "io": 3,
    "datasets": 4, "semantics": 4, "evaluation": 4,
    "rendering": 5, "gt": 5, "gt_config": 5,
    "mapping": 6,
    "baselines": 7, "views": 7, "demo": 7, "slam": 7, "viz": 7,
    "benchmark": 8,
    "cli": 9, "__main__": 10, "__init__": 10,
}

# modules of mapping/ and semantics/ that are maths: no file access, no printing, no progress bars
RUNNERS = {"mapping/pipeline.py", "mapping/bench.py", "mapping/o3d_tsdf.py", "mapping/semantic.py",
           "mapping/mapper.py", "mapping/rpu.py", "semantics/precomputed.py", "slam/run.py"}
FILE_CALLS = {"open", "print", "imread", "imwrite", "load", "save", "savez", "savez_compressed", "tqdm",
              "read_text", "write_text", "read_bytes", "write_bytes", "fromfile", "tofile"}


def _part(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imports(path: Path):
    """(line, imported top-level part of panovocc_cli) of every import in ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    rel = path.relative_to(PKG)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                base = list(rel.parts[:-1])[: len(rel.parts) - node.level]
                target = base + (node.module.split(".") if node.module else [])
                if not target:  # "from . import x" at the top
                    target = [node.names[0].name]
            elif node.module and node.module.split(".")[0] == "panovocc_cli":
                target = node.module.split(".")[1:] or [node.names[0].name]
            else:
                continue
            yield node.lineno, target[0]
        elif isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] == "panovocc_cli" and len(parts) > 1:
                    yield node.lineno, parts[1]


MODULES = sorted(p for p in PKG.rglob("*.py"))


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


MATHS = [p for p in MODULES if _part(p) in ("mapping", "semantics", "geometry", "slam")
         and str(p.relative_to(PKG)) not in RUNNERS]


@pytest.mark.parametrize("path", MATHS, ids=lambda p: str(p.relative_to(PKG)))
def test_maths_modules_read_no_files_and_print_nothing(path):
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
    assert not bad, f"{path.relative_to(PKG)} does I/O or prints: {bad}"
