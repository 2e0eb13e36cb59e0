"""The README's benchmark tables are the committed results folder's (panovocc_cli/benchmark/readme.py)."""

from pathlib import Path

import pytest

from panovocc_cli.benchmark.readme import current_block, readme_block, table_text, update_readme
from panovocc_cli.errors import PanovoccError

ROOT = Path(__file__).resolve().parents[2]


def test_readme_tables_are_the_committed_results():
    folder, block = current_block(ROOT / "README.md")
    assert (ROOT / folder / "benchmark.json").is_file(), folder
    assert block == readme_block(ROOT, folder), "README out of date: python -m panovocc_cli.benchmark.readme README.md"


def test_table_text_drops_provenance_and_demotes_title():
    md = "## Main\n\n| a |\n|---|\n| 1 |\n\n- note\n\nProvenance: code x.\n\n- row: cmd\n"
    assert table_text(md) == "### Main\n\n| a |\n|---|\n| 1 |\n\n- note"


def test_update_readme_rewrites_only_the_block(tmp_path):
    res = tmp_path / "res"
    (res / "figures").mkdir(parents=True)
    for stem in ("main_pan-replica-synth", "main_pan-holo-synth", "ablation", "upstream"):
        (res / f"{stem}.md").write_text(f"## {stem}\n\n| x |\n|---|\n| 1 |\n\nProvenance: p\n")
    readme = tmp_path / "README.md"
    readme.write_text("head\n<!-- BENCHMARK-TABLES res -->\nold\n<!-- /BENCHMARK-TABLES -->\ntail\n")
    assert update_readme(readme)
    text = readme.read_text()
    assert text.startswith("head\n<!-- BENCHMARK-TABLES res -->\n### main_pan-replica-synth") and text.endswith(
        "<!-- /BENCHMARK-TABLES -->\ntail\n")
    assert "old" not in text and "Provenance" not in text
    assert not update_readme(readme)  # idempotent
    (res / "ablation.md").unlink()
    with pytest.raises(PanovoccError, match="ablation.md"):
        update_readme(readme)


@pytest.mark.parametrize("name", ["missing.md", "no_block.md"])
def test_bad_readme_is_one_line_and_exit_2(tmp_path, name):
    import subprocess
    import sys

    (tmp_path / "no_block.md").write_text("# a README without the block\n")
    r = subprocess.run([sys.executable, "-m", "panovocc_cli.benchmark.readme", str(tmp_path / name)],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: ") and name in r.stderr
    assert (tmp_path / "no_block.md").read_text() == "# a README without the block\n"  # nothing written
