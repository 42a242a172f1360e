"""The README's headline table (``benchmarks/headline.py``) is what the documents' figure blocks
say today: a block measured again and not carried into the table fails here."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import headline
from benchmarks.figures import FigureError
from tests.conftest import ROOT


def _copy(tmp: Path) -> Path:
    root = tmp / "checkout"
    root.mkdir()
    shutil.copy(ROOT / "README.md", root / "README.md")
    shutil.copytree(ROOT / "docs", root / "docs")
    return root


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def test_the_readmes_headline_table_is_what_the_blocks_say_today():
    readme = (ROOT / "README.md").read_text()
    assert headline.current(readme) == headline.table(ROOT), (
        "README.md's headline table differs from the documents' blocks: run "
        "scripts/figures --headline"
    )
    assert len(headline.table(ROOT).split("\n")) == 2 + len(headline.ROWS)


def test_a_block_measured_again_makes_the_table_stale_until_it_is_rewritten(tmp_path):
    """The occupancy block's ratio changed in its document: the README's table no longer
    matches, the new table carries the new figure and the block's new commit and day, and
    ``scripts/figures --headline`` writes it."""
    root = _copy(tmp_path)
    doc = root / "docs" / "benchmarks.md"
    block = next(b for b in headline.parse_blocks(doc.read_text()) if b.name == "occupancy")
    old = headline.summary_lines(block.body)[0]["like_for_like_vs_octomap"]
    _edit(doc, f"like_for_like_vs_octomap={old} ", "like_for_like_vs_octomap=2.04 ")
    made = headline.parse_provenance(block.body[0])
    _edit(doc, f"· {made['commit']} · {made['when']}", "· abcdef1 · 2027-01-02 03:04 UTC")
    table = headline.table(root)
    assert headline.current((root / "README.md").read_text()) != table
    row = next(r for r in table.split("\n") if r.startswith("| occupancy map"))
    assert "×2.04 faster" in row and "[abcdef1, 2027-01-02](docs/benchmarks.md#" in row, row
    subprocess.run([sys.executable, "-m", "benchmarks.figures", "--headline"], cwd=root,
                   check=True, env={"PYTHONPATH": str(ROOT)}, capture_output=True)  # fmt: skip
    assert headline.current((root / "README.md").read_text()) == table


def test_a_row_whose_figure_lost_its_field_or_line_fails_naming_it(tmp_path):
    root = _copy(tmp_path)
    doc = root / "docs" / "benchmarks.md"
    _edit(doc, "like_for_like_vs_pyransac3d=", "vs_pyransac3d=")
    with pytest.raises(FigureError, match=r"perception.*like_for_like_vs_pyransac3d"):
        headline.table(root)
    (tmp_path / "b").mkdir()
    root2 = _copy(tmp_path / "b")
    _edit(root2 / "docs" / "real-data.md", "recording=redkitchen-a dof=planar odometry_noise=0.02",
          "recording=redkitchen-a dof=planar odometry_noise=0.03")  # fmt: skip
    with pytest.raises(FigureError, match=r"real_data.*odometry_noise"):
        headline.table(root2)


def test_lines_are_picked_by_their_fields():
    body = (
        "`cmd` · abc1234 · 2026-12-05 03:12 UTC · reference 31 ms before",
        "",
        "`recording=a frames=3 ms=1`",
        "`recording=b dof=planar x=2`",
        "| a | table |",
    )
    lines = headline.summary_lines(body)
    assert [line["recording"] for line in lines] == ["a", "b"]
    assert headline.pick(lines, {"recording": "b"})["x"] == "2"
    assert headline.pick(lines, {"frames": "*"})["recording"] == "a"
    assert headline.pick(lines, {"recording": "c"}) is None


def test_links_point_at_the_heading_above_the_block_as_github_anchors_it():
    assert headline.slug("## Exploring live: `avs up --explore`, `docker compose up`") == (
        "exploring-live-avs-up---explore-docker-compose-up"
    )
    assert headline.slug("## On real recordings") == "on-real-recordings"
    for row in headline.table(ROOT).split("\n")[2:]:
        link = row.rsplit("](", 1)[1].rstrip(") |")
        doc, anchor = link.split("#")
        headings = [headline.slug(h) for h in (ROOT / doc).read_text().split("\n")
                    if h.startswith("#")]  # fmt: skip
        assert anchor in headings, (row, headings)
