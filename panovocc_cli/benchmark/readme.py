"""The README's benchmark tables, generated from a results folder so that the README cannot drift from it.

The README holds a block between ``<!-- BENCHMARK-TABLES FOLDER -->`` and ``<!-- /BENCHMARK-TABLES -->``;
:func:`readme_block` rebuilds its content from ``FOLDER`` (the tables' Markdown files without their
provenance lists, which stay in the folder, and the coverage figure), and :func:`update_readme` writes it
in place. ``tests/benchmark/test_readme.py`` checks the committed README against the committed results.

    python -m panovocc_cli.benchmark.readme README.md     # after make reproduce-tables
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from ..errors import EXIT_BAD_INPUT, PanovoccError

BEGIN = re.compile(r"<!-- BENCHMARK-TABLES (\S+) -->\n")
END = "<!-- /BENCHMARK-TABLES -->"
#: the tables shown, in order (file stems in the results folder); the rest stay in the folder
SHOWN = ("main_pan-replica-synth", "main_pan-holo-synth", "ablation", "upstream")
FIGURE = "figures/coverage_pan-replica-synth.png"


def table_text(md: str) -> str:
    """A results table's Markdown without its provenance (everything from the ``Provenance:`` line on);
    its ``##`` title becomes ``###``."""
    body = md.split("\nProvenance:", 1)[0].rstrip()
    return re.sub(r"^## ", "### ", body, count=1, flags=re.M)


def readme_block(root: Path, folder: str) -> str:
    """The block's content for results folder ``folder`` (relative to the README's folder ``root``)."""
    d = root / folder
    parts = []
    for stem in SHOWN:
        path = d / f"{stem}.md"
        if not path.is_file():
            raise PanovoccError("not found: run make reproduce-tables first (or name another results folder)", path)
        parts.append(table_text(path.read_text()))
    if (d / FIGURE).is_file():
        parts.append(f"![coverage, panoramic vs perspective]({folder}/{FIGURE})\n\nCoverage of the ground truth's "
                     "occupied voxels along the trajectory of pan-replica-synth's first scene: all panoramas seen so "
                     "far against the same frames' forward 90° views (every scene: the coverage table).")
    parts.append(f"Per-scene cells, the coverage table and the provenance of every row: `{folder}/`.")
    return "\n\n".join(parts) + "\n"


def _span(text: str, where) -> tuple[re.Match, int]:
    m = BEGIN.search(text)
    end = text.find(END, m.end()) if m else -1
    if m is None or end < 0:
        raise PanovoccError(f"no '<!-- BENCHMARK-TABLES FOLDER -->' ... '{END}' block", where)
    return m, end


def _read(readme: Path) -> str:
    if not readme.is_file():
        raise PanovoccError("not found (expected the README with a BENCHMARK-TABLES block)", readme)
    return readme.read_text()


def current_block(readme: Path) -> tuple[str, str]:
    """``(folder, content)`` of the README's block as it stands."""
    text = _read(readme)
    m, end = _span(text, readme)
    return m.group(1), text[m.end():end]


def update_readme(readme: Path) -> bool:
    """Rewrite the README's block from its results folder; True when it changed."""
    from ..io.atomic import write_text

    text = _read(readme)
    m, end = _span(text, readme)
    new = text[:m.end()] + readme_block(readme.parent, m.group(1)) + text[end:]
    if new == text:
        return False
    write_text(readme, new)
    return True


if __name__ == "__main__":  # python -m panovocc_cli.benchmark.readme README.md
    try:
        changed = update_readme(Path(sys.argv[1] if len(sys.argv) > 1 else "README.md"))
    except PanovoccError as e:  # one line, exit status 2, as every panovocc command
        print(f"error: {e}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    print("README updated" if changed else "README already up to date")
