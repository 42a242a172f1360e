"""The README's headline figures (issue 44): one short table whose every number is read from a
figure block in ``docs/`` (``benchmarks/figures.py``), with a link to it and the commit and day
that block was measured. Nothing is measured here: the table is derived, so it cannot say more
than the blocks do, and ``scripts/figures`` rewrites it whenever it rewrites a block
(``scripts/figures --headline``: only the table). ``tests/test_headline.py`` fails when the
README's table is not what the documents' blocks give today.

The table sits in the README between ``<!-- headline -->`` and ``<!-- /headline -->``.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.figures import (
    ROOT,
    FigureError,
    documents,
    find_blocks,
    parse_blocks,
    parse_provenance,
    write_text,
)

OPEN, CLOSE = "<!-- headline -->", "<!-- /headline -->"
HEADER = "| what | AVS | against | measured |"
CODE_SPAN = re.compile(r"^`([^`]+)`$")

Fields = Mapping[str, str]


def _x(v: str) -> str:
    return f"×{float(v):.3g}"


@dataclass(frozen=True)
class Row:
    """A row: ``what`` is measured, read from figure ``figure``'s summary line whose fields
    include ``select`` (a block may hold a line per recording); ``ours`` and ``against`` turn
    that line's fields into the row's two cells."""

    what: str
    figure: str
    ours: Callable[[Fields], str]
    against: Callable[[Fields], str]
    select: dict[str, str] = field(default_factory=dict)


ROWS: tuple[Row, ...] = (
    Row(
        "occupancy map, integrating a 640×480 view at 1 cm",
        "occupancy",
        lambda f: f"{f['integrate_ms_1cm']} ms",
        lambda f: f"OctoMap (pyoctomap): {_x(f['like_for_like_vs_octomap'])} faster, like for like",
    ),
    Row(
        "primitive fitting (Algorithm 1), one frame",
        "perception",
        lambda f: f"{f['perception_ms']} ms, InlierIndex {f['inlier_index']}",
        lambda f: (
            f"pyRANSAC-3D: {_x(f['like_for_like_vs_pyransac3d'])} faster, InlierIndex "
            f"{f['inlier_index_pyransac3d']}"
        ),
    ),
    Row(
        "view registration (point-to-plane ICP), a simulated frame",
        "registration",
        lambda f: f"{f['registration_ms']} ms, {float(f['pose_error_mm']):.1f} mm off",
        lambda f: f"Open3D ICP: {_x(f['like_for_like_vs_open3d_p2l'])} faster, like for like",
    ),
    Row(
        "next-best-view ray casting",
        "nbv",
        lambda f: f"{float(f['rays_per_s']) / 1e6:.1f} M rays/s",
        lambda f: (
            f"Open3D's Embree: {_x(f['like_for_like_vs_embree'])} (slower, like for like)"
            if float(f["like_for_like_vs_embree"]) < 1
            else f"Open3D's Embree: {_x(f['like_for_like_vs_embree'])} faster, like for like"
        ),
    ),
    Row(
        "gaze stabiliser's control loop",
        "gaze",
        lambda f: f"{f['loop_hz']} Hz, latency p99 {f['latency_p99_ms']} ms",
        lambda f: "target 1 kHz (thesis ch. 5)",
    ),
    Row(
        "exploration, generated scenes (sensor models on)",
        "generalization",
        lambda f: (
            f"support F1 {f['f1_final_mean']} (mean of {f['scenes']} scenes; p10 "
            f"{f['f1_final_p10']})"
        ),
        lambda f: f"after the first view: {f['f1_view1_mean']}",
    ),
    Row(
        "… a second subset of the generator (seeds 5000-5029)",
        "generalization_5000",
        lambda f: (
            f"support F1 {f['f1_final_mean']} (mean of {f['scenes']} scenes; p10 "
            f"{f['f1_final_p10']})"
        ),
        lambda f: f"after the first view: {f['f1_view1_mean']}",
    ),
    Row(
        "exploration by the live stack (`avs up --explore`)",
        "live_explore",
        lambda f: f"support F1 {f['live_f1_mean']} (mean of {f['scenes']} scenes)",
        lambda f: f"the same scenes in lockstep: {f['lockstep_f1_mean']}",
    ),
    Row(
        "a real Kinect v1 kitchen (7-Scenes), perception",
        "real_data",
        lambda f: f"{f['perception_ms']} ms a frame, {float(f['unstable_share']):.1%} unstable",
        lambda f: "targets: ≤ 60 ms, ≤ 5 %",
        {"recording": "redkitchen-a", "observations": "*"},
    ),
    Row(
        "… its camera pose with odometry drift injected",
        "real_data",
        lambda f: f"{f['pose_error_mm']} mm off at the end (registrations weighed)",
        lambda f: f"the drift alone: {f['drift_error_mm']} mm",
        {"recording": "redkitchen-a", "dof": "planar", "odometry_noise": "0.02"},
    ),
)


def summary_lines(body: tuple[str, ...] | list[str]) -> list[dict[str, str]]:
    """The ``key=value …`` lines of a block's body that stand alone in a code span."""
    out = []
    for line in body:
        m = CODE_SPAN.match(line.strip())
        if not m or "=" not in m[1]:
            continue
        pairs = [p.split("=", 1) for p in m[1].split()]
        if all(len(p) == 2 for p in pairs):
            out.append(dict(pairs))
    return out


def pick(lines: list[dict[str, str]], select: Mapping[str, str]) -> dict[str, str] | None:
    """The first line with every field of ``select`` (``*``: the field is there at all)."""
    for fields in lines:
        if all(k in fields and (v == "*" or fields[k] == v) for k, v in select.items()):
            return fields
    return None


def slug(heading: str) -> str:
    """A markdown heading's anchor as GitHub makes it: lower case, punctuation dropped,
    spaces as hyphens."""
    text = unicodedata.normalize("NFC", heading.strip().lstrip("#").strip().lower())
    text = "".join(c for c in text if c.isalnum() or c in " -_")
    return text.replace(" ", "-")


def _heading_above(text: str, line: int) -> str | None:
    lines = text.split("\n")
    for raw in reversed(lines[:line]):
        if raw.startswith("#"):
            return raw
    return None


def table(root: Path = ROOT) -> str:
    """The headline table as the documents under ``root`` give it (FigureError for a row whose
    block or line is missing, or whose figure's line lacks a field it reads)."""
    from benchmarks.figures import REGISTRY

    where = find_blocks(documents(root), REGISTRY)
    rows = [HEADER, "|---|---|---|---|"]
    for row in ROWS:
        doc = where.get(row.figure)
        if doc is None:
            raise FigureError(f"headline {row.what!r}: no block for figure {row.figure!r}")
        text = doc.read_text()
        block = next(b for b in parse_blocks(text) if b.name == row.figure)
        fields = pick(summary_lines(block.body), row.select)
        if fields is None:
            raise FigureError(f"headline {row.what!r}: figure {row.figure!r} has no line with "
                              f"{row.select}")  # fmt: skip
        try:
            ours, against = row.ours(fields), row.against(fields)
        except (KeyError, ValueError) as e:
            raise FigureError(f"headline {row.what!r}: figure {row.figure!r}: {e!r}") from None
        made = parse_provenance(block.body[0]) if block.body else None
        day = made["when"][:10] if made else "?"
        commit = made["commit"] if made else "?"
        heading = _heading_above(text, block.open_line)
        link = doc.relative_to(root).as_posix() + (f"#{slug(heading)}" if heading else "")
        rows.append(f"| {row.what} | {ours} | {against} | [{commit}, {day}]({link}) |")
    return "\n".join(rows)


def replace(readme: str, content: str) -> str:
    """``readme`` with the lines between the headline markers replaced by ``content``."""
    lines = readme.split("\n")
    try:
        a, b = lines.index(OPEN), lines.index(CLOSE)
    except ValueError:
        raise FigureError(f"README.md has no {OPEN} … {CLOSE} block") from None
    if b < a:
        raise FigureError(f"README.md: {CLOSE} before {OPEN}")
    return "\n".join([*lines[: a + 1], "", content, "", *lines[b:]])


def current(readme: str) -> str:
    """The table between the README's headline markers, as it stands."""
    lines = readme.split("\n")
    a, b = lines.index(OPEN), lines.index(CLOSE)
    return "\n".join(lines[a + 1 : b]).strip()


def rewrite(root: Path = ROOT) -> bool:
    """Rewrite the README's headline table from the documents' blocks; whether it changed."""
    path = root / "README.md"
    text = path.read_text()
    new = replace(text, table(root))
    if new != text:
        write_text(path, new)
    return new != text
