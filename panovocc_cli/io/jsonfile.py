"""JSON files read with one clear error line for a missing or malformed file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import PanovoccError


def read_json(path: str | Path, expected: str) -> Any:
    """Parse a JSON file; ``expected`` (e.g. "Replica's info_semantic.json") names what should be there.

    Raises :class:`PanovoccError` naming the file when it is missing, not UTF-8 or not valid JSON.
    """
    path = Path(path)
    if not path.is_file():
        raise PanovoccError(f"file not found (expected {expected})", path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise PanovoccError(f"invalid JSON ({getattr(e, 'msg', e)}; expected {expected})", path) from None
