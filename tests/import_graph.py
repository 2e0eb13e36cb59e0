"""The package's import graph, read from the code's own import statements (those inside functions too,
which run when the function first does): what tests/test_layers.py and the benchmark's code fingerprint
test check. Modules are named by their path below ``panovocc_cli`` (``mapping.pipeline``; a package by its
folder, ``mapping``)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "panovocc_cli"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def imported_modules(path: Path):
    """(line, module) of every import of a package module in ``path``, wherever it stands; ``from X import
    name`` names ``X.name`` when that is a module, else ``X``."""
    tree = ast.parse(path.read_text(), str(path))
    package = list(path.relative_to(PKG).parts[:-1])
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
            elif node.module and node.module.split(".")[0] == "panovocc_cli":
                base = node.module.split(".")[1:]
            else:
                continue
            for alias in node.names:
                sub = ".".join(base + [alias.name])
                if sub in MODULES:
                    yield node.lineno, sub
                elif ".".join(base) in MODULES:
                    yield node.lineno, ".".join(base)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "panovocc_cli" and ".".join(parts[1:]) in MODULES:
                    yield node.lineno, ".".join(parts[1:])


def import_graph() -> dict[str, set[str]]:
    """module -> the modules it imports."""
    return {m: {t for _, t in imported_modules(p) if t != m} for m, p in MODULES.items()}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The sets of two or more modules that import each other in a loop (strongly connected components)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):  # Tarjan's algorithm, iterative: (node, its successors still to see)
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        while work:
            node, succ = work[-1]
            for w in succ:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """``start`` and every module it imports, directly or through others."""
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph[m])
    return seen
