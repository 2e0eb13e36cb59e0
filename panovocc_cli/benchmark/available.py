"""What this build can run: a requirement is checked by importing it, never assumed.

A requirement is a string ``module``, ``module:attr`` or ``module:Class.field`` (a dataclass field, e.g.
``panovocc_cli.datasets.synth:SynthConfig.house``). A method or split whose requirements do not all
import is reported as "not available in this build" with the first missing one named; nothing is run
for it and no number is made up. :func:`select_named` picks entries of such a registry (methods, splits)
by name.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Iterable

from ..errors import PanovoccError


def missing(requires: Iterable[str]) -> list[str]:
    """The requirements of ``requires`` that this build lacks, in order (empty: all present)."""
    return [r for r in requires if not _has(r)]


def _has(req: str) -> bool:
    module, _, attr = req.partition(":")
    try:
        obj = importlib.import_module(module)
    except ImportError:
        return False
    if not attr:
        return True
    head, _, fld = attr.partition(".")
    obj = getattr(obj, head, None)
    if obj is None:
        return False
    if not fld:
        return True
    if dataclasses.is_dataclass(obj):
        return any(f.name == fld for f in dataclasses.fields(obj))
    return hasattr(obj, fld)


def unavailable_reason(requires: Iterable[str]) -> str | None:
    """``None`` when every requirement imports, else ``"not available in this build (needs X)"``."""
    lack = missing(requires)
    return None if not lack else f"not available in this build (needs {', '.join(lack)})"


def select_named(registry: dict, spec: str, what: str) -> list:
    """The entries of ``registry`` (name -> entry) named by the comma list ``spec`` (``all``: every entry), in
    registry order; an unknown name, or a list that names nothing (``''``, ``,,``), is a
    :class:`PanovoccError` naming the option ``--{what}s`` and the choices (``what``: the kind of entry, e.g.
    ``method``)."""
    names = [n.strip() for n in spec.split(",") if n.strip()]
    if not names:
        raise PanovoccError(f"--{what}s {spec!r} names no {what}: expected all or a comma list of "
                            f"{', '.join(registry)}")
    if names == ["all"]:
        return list(registry.values())
    bad = [n for n in names if n not in registry]
    if bad:
        raise PanovoccError(f"unknown {what} {bad[0]!r}: expected all or a comma list of {', '.join(registry)}")
    return [v for k, v in registry.items() if k in names]
