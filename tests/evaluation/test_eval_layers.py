"""The layer rule of evaluation/: its modules do maths and build figures; only the runners run.py and
trajectory_run.py read and write files (through io/), and io/ never imports evaluation/."""

import ast
from pathlib import Path

import panovocc_cli

PKG = Path(panovocc_cli.__file__).parent
FILE_CALLS = {"open", "savefig", "write_text", "write_bytes", "read_text", "read_bytes", "save", "savez",
              "savez_compressed", "load", "imwrite", "imread", "mkdir", "unlink", "replace", "rename"}


def imported_modules(tree, pkg_parts):
    """Absolute dotted names a module imports (relative imports resolved against its package)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = pkg_parts[: len(pkg_parts) - node.level + 1] if node.level else []
            out.append(".".join(base + ([node.module] if node.module else [])))
    return out


def test_evaluation_maths_modules_touch_no_files():
    for path in sorted((PKG / "evaluation").glob("*.py")):
        if path.name in ("run.py", "trajectory_run.py", "__init__.py"):  # the runners (and the package)
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        mods = imported_modules(tree, ["panovocc_cli", "evaluation"])
        assert not [m for m in mods if m.startswith("panovocc_cli.io")], path.name
        calls = {n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, "id", None)
                 for n in ast.walk(tree) if isinstance(n, ast.Call)}
        assert not calls & FILE_CALLS, (path.name, calls & FILE_CALLS)
        assert "print" not in calls, path.name


def test_io_does_not_import_evaluation():
    for path in sorted((PKG / "io").glob("*.py")):
        mods = imported_modules(ast.parse(path.read_text(encoding="utf-8")), ["panovocc_cli", "io"])
        assert not [m for m in mods if m.startswith("panovocc_cli.evaluation")], path.name
