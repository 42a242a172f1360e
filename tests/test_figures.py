"""scripts/figures (benchmarks/figures.py): the figure blocks of the README and ``docs/`` parse
and name their commands, a block is rewritten in place in its own document and nothing else is,
unknown blocks fail, every measured table of the documents is inside a block, and each renderer
turns a run's output (canned here from real runs: the numbers are checked) into its block. No
figure is measured here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

import pytest

from benchmarks import figures
from benchmarks.figures import (
    REGISTRY,
    Figure,
    FigureError,
    RenderError,
    block_content,
    check_blocks,
    documents,
    find_blocks,
    loose_tables,
    parse_blocks,
    parse_provenance,
    provenance,
    replace_block,
)
from tests.conftest import ROOT

WHEN = datetime(2026, 12, 5, 3, 12, 40, tzinfo=timezone.utc)


def blocks_name_their_commands(text: str) -> list[str]:
    """Every block of ``text`` parses, names a registry figure, and its first line is a
    provenance line naming that figure's command; returns the names."""
    names = []
    for b in check_blocks(text, REGISTRY):
        assert b.body, f"figure {b.name!r}: an empty block"
        fields = parse_provenance(b.body[0])
        assert fields, f"figure {b.name!r}: its first line is no provenance: {b.body[0]!r}"
        assert REGISTRY[b.name].matches(fields["command"]), (b.name, fields["command"])
        names.append(b.name)
    return names


def block(name: str, body: str, command: str | None = None) -> str:
    command = command or REGISTRY[name].shown(Path(f"runs/figures/{name}"))
    line = provenance(command, "cd56edf", WHEN, 31.2, 30.8)
    return f"<!-- figure: {name} -->\n{block_content(line, body)}<!-- /figure -->"


# -- blocks -------------------------------------------------------------------------------------


def test_the_documents_blocks_parse_and_name_their_figures_commands():
    names = [n for d in documents(ROOT) for n in blocks_name_their_commands(d.read_text())]
    assert sorted(names) == sorted(REGISTRY)  # each figure has one block, in one document
    assert set(find_blocks(documents(ROOT), REGISTRY)) == set(REGISTRY)


def test_a_block_for_every_figure_names_its_command_and_a_wrong_command_fails():
    text = "\n\n".join(["# AVS", *(block(n, "`a=1`") for n in REGISTRY), "The end."])
    assert blocks_name_their_commands(text) == list(REGISTRY)
    f = parse_provenance(parse_blocks(text)[0].body[0])
    assert f == {"command": "python benchmarks/codec.py", "commit": "cd56edf",
                 "when": "2026-12-05 03:12 UTC", "before": "31.2", "after": "30.8"}  # fmt: skip
    # the command of another figure, or another out dir's spelling of the same, in a block
    wrong = block("codec", "`a=1`", command="python benchmarks/sim.py")
    with pytest.raises(AssertionError, match="codec"):
        blocks_name_their_commands(wrong)
    elsewhere = block("soak", "x", command="python benchmarks/soak.py --minutes 3 --out /tmp/s")
    assert blocks_name_their_commands(elsewhere) == ["soak"]
    longer = block("soak", "x", command="python benchmarks/soak.py --minutes 10 --out /tmp/s")
    with pytest.raises(AssertionError):
        blocks_name_their_commands(longer)
    assert parse_provenance("`python benchmarks/codec.py` measured today") is None


README_TEXT = """# Title

Some prose that stays.

<!-- figure: codec -->
`python benchmarks/codec.py` · 1234567 · 2026-12-01 10:00 UTC · reference 40 ms before

`codec_fps=4000 latency_p50_ms=3.00 latency_p99_ms=7.00`

<!-- /figure -->

More prose, and a format shown in fenced code (not a block):

```
<!-- figure: not_a_figure -->
```

<!-- figure: soak -->
{soak_provenance}
old table
<!-- /figure -->
Trailing text.
""".replace(
    "{soak_provenance}",
    "`python benchmarks/soak.py --minutes 3 --out runs/figures/soak` · 1234567 · "
    "2026-12-01 10:05 UTC · reference 40 ms before",
)


def test_rewriting_a_block_replaces_exactly_that_block(tmp_path):
    (tmp_path / "soak.json").write_text(json.dumps(SOAK))
    body = figures.render_soak(SOAK_STDOUT, tmp_path)
    command = "python benchmarks/soak.py --minutes 3 --out runs/figures/soak"
    content = block_content(provenance(command, "cd56edf+dirty", WHEN, 31.2), body)
    new = replace_block(README_TEXT, "soak", content)
    before = README_TEXT.split("<!-- figure: soak -->")[0]
    assert new.startswith(before + "<!-- figure: soak -->\n")  # the codec block untouched
    assert new.endswith("<!-- /figure -->\nTrailing text.\n")
    assert "old table" not in new and "| 1 | 1000 | 968 | 969 | 15.0 | 5.98 | 359 |" in new
    (old_codec, _), (new_codec, new_soak) = parse_blocks(README_TEXT), parse_blocks(new)
    assert new_codec == old_codec
    assert new_soak.body[0].endswith(
        "· cd56edf+dirty · 2026-12-05 03:12 UTC · reference 31.2 ms before"
    )
    assert new_soak.body[1] == "" and new_soak.body[-1] == ""
    assert blocks_name_their_commands(new) == ["codec", "soak"]
    # the same again changes nothing; another body only that block
    assert replace_block(new, "soak", content) == new
    again = replace_block(new, "codec", block_content(new_codec.body[0], "`x=1`"))
    assert again.replace("`x=1`", "`codec_fps=4000 latency_p50_ms=3.00 latency_p99_ms=7.00`") == (
        new
    )


def test_unknown_broken_and_doubled_blocks_fail(tmp_path, capsys):
    unknown = README_TEXT.replace("figure: soak", "figure: soak_10min")
    with pytest.raises(FigureError, match="soak_10min"):
        check_blocks(unknown, REGISTRY)
    for text, what in (
        (README_TEXT.replace("old table\n<!-- /figure -->", "old table"), "never closed"),
        (README_TEXT.replace("old table", "<!-- figure: sim -->"), "inside"),
        (README_TEXT.replace("# Title", "<!-- /figure -->"), "without"),
        (README_TEXT.replace("figure: soak", "figure: codec"), "two blocks"),
        (README_TEXT.replace("<!-- figure: soak -->", "<!-- figure soak -->"), "not a figure"),
    ):
        with pytest.raises(FigureError, match=what):
            parse_blocks(text)
    with pytest.raises(FigureError, match="no block"):
        replace_block(README_TEXT, "sim", "x")
    # the command refuses such a README before it runs anything
    readme = tmp_path / "README.md"
    readme.write_text(unknown)
    assert figures.main(["--readme", str(readme), "--out", str(tmp_path / "out")]) == 2
    assert "soak_10min" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and readme.read_text() == unknown


def test_blocks_in_two_documents_each_rewritten_in_its_own_and_a_figure_in_both_fails(tmp_path):
    readme, doc = tmp_path / "README.md", tmp_path / "docs" / "benchmarks.md"
    doc.parent.mkdir()
    readme.write_text("# AVS\n\n" + block("codec", "`a=1`") + "\n")
    doc.write_text("# Benchmarks\n\n" + block("soak", "`b=2`") + "\n")
    assert documents(tmp_path) == [readme, doc]
    where = find_blocks(documents(tmp_path), REGISTRY)
    assert where == {"codec": readme, "soak": doc}
    ok = Figure("soak", "python -c \"print('a=7 b=8')\"", 1, figures.render_summary)
    assert figures.run([ok], where, tmp_path / "out") == 0
    (soak,) = parse_blocks(doc.read_text())
    assert soak.body[2] == "`a=7 b=8`" and "`a=1`" in readme.read_text()
    doc.write_text(doc.read_text() + "\n" + block("codec", "`a=3`") + "\n")
    with pytest.raises(FigureError, match=r"codec.*README\.md and .*benchmarks\.md"):
        find_blocks(documents(tmp_path), REGISTRY)


def test_every_measured_table_of_the_documents_is_in_a_figure_block():
    loose = [(d.name, n, h) for d in documents(ROOT) for n, h in loose_tables(d.read_text())]
    assert not loose, "measured tables outside figure blocks (file, line, header):\n" + "\n".join(
        f"  {d}:{n}: {h}" for d, n, h in loose
    )


def test_a_table_outside_the_blocks_is_found_unless_it_is_a_reference_table():
    text = (
        "| service | thesis | consumes | produces |\n|---|---|---|---|\n| sim | B | a | b |\n\n"
        "| minute | IMU Hz |\n|---|---|\n| 1 | 1000 |\n\n"
        "```\n| in | code |\n|---|---|\n```\n\n"
        + block("gaze_exposure", "| localised | off | on |\n|---|---|---|\n| cup | 41 % | 100 % |")
    )  # fmt: skip
    assert figures.table_headers(text) == [
        (1, "| service | thesis | consumes | produces |"),
        (5, "| minute | IMU Hz |"),
        (17, "| localised | off | on |"),
    ]
    assert loose_tables(text) == [(5, "| minute | IMU Hz |")]


# -- the command --------------------------------------------------------------------------------


def test_scripts_figures_help_and_list_run():
    env = dict(os.environ, AVS_VENV=sys.prefix)
    help_ = subprocess.run([str(ROOT / "scripts/figures"), "--help"], env=env, text=True,
                           capture_output=True, timeout=120)  # fmt: skip
    assert help_.returncode == 0, help_.stderr
    for flag in ("--list", "--only", "--skip", "--readme", "--out", "--dry-run"):
        assert flag in help_.stdout
    listed = subprocess.run([str(ROOT / "scripts/figures"), "--list"], env=env, text=True,
                            capture_output=True, timeout=120).stdout.splitlines()  # fmt: skip
    assert [line.split()[0] for line in listed] == [*REGISTRY, "total"]
    assert listed[-1].split()[1] == f"{sum(f.minutes for f in REGISTRY.values()):g}"
    assert listed[0].split(None, 3)[3] == "python benchmarks/codec.py"


def test_a_failing_figure_leaves_its_block_and_the_others_still_run(tmp_path, monkeypatch):
    """Two figures: the first fails (exit 3), the second prints progress and its summary. The
    first's block stays as it was, the second's is rewritten with both reference speeds, the
    exit status is 1, and each one's output is in its log."""
    ok = Figure("codec", "python -c \"print('progress'); print('a=1 b=2')\"", 1,
                figures.render_summary)  # fmt: skip
    bad = Figure("soak", "python -c \"import sys; print('half way'); sys.exit(3)\"", 1,
                 figures.render_soak)  # fmt: skip
    speeds = iter([30.0, 31.5])
    monkeypatch.setattr(figures, "reference", lambda: next(speeds))
    readme = tmp_path / "README.md"
    readme.write_text(README_TEXT)
    out = tmp_path / "out"
    assert figures.run([bad, ok], {"codec": readme, "soak": readme}, out) == 1
    text = readme.read_text()
    (codec, soak), (_, old_soak) = parse_blocks(text), parse_blocks(README_TEXT)
    assert soak == old_soak
    assert codec.body[2] == "`a=1 b=2`"
    assert codec.body[0].endswith("· reference 30 ms before, 31.5 ms after")
    assert text.split("<!-- figure: soak -->")[1] == README_TEXT.split("<!-- figure: soak -->")[1]
    assert "half way" in (out / "soak.log").read_text()
    assert "progress" in (out / "codec.log").read_text()
    assert (out / "codec.md").read_text() == "\n".join(codec.body) + "\n"
    assert not (out / "soak.md").exists()


# -- renderers, on outputs canned from real runs ------------------------------------------------

CODEC_STDOUT = """codec: one 640×480 RGB-D frame (rgb uint8 + depth float32), median ms
                          encode   decode round trip  frames/s  ÷ ours     bytes
  ours                     0.061    0.160      0.222    4504.5   1.00×   2150581
latency: 300 frames at 30 Hz, publisher → router → subscriber
  received 300/300  p50 2.61 ms  p99 6.48 ms  max 9.12
codec_fps=4505 latency_p50_ms=2.61 latency_p99_ms=6.48
"""


def test_a_benchmark_renders_its_last_line_in_a_code_span(tmp_path):
    assert figures.render_summary(CODEC_STDOUT, tmp_path) == (
        "`codec_fps=4505 latency_p50_ms=2.61 latency_p99_ms=6.48`"
    )
    with pytest.raises(RenderError, match="not a key=value"):
        figures.render_summary(CODEC_STDOUT + "wrote nothing\n", tmp_path)
    with pytest.raises(RenderError, match="nothing"):
        figures.render_summary("\n \n", tmp_path)


PIPELINE = {  # benchmarks/pipeline.py --out DIR, 2026-12-05 01:57 UTC (frames left out)
    "summary": {"fps_in": 13.84, "fps_semantic": 5.89, "fps_mapped": 4.61,
                "frame_to_semantic_p50_ms": 334.4, "frame_to_semantic_p99_ms": 1296.8,
                "frame_to_map_p50_ms": 258.9, "frame_to_map_p99_ms": 1055.7,
                "frame_to_observation_p50_ms": 203.3, "cpu_percent": 197.7},
    "stages": {
        "arrived": {"n": 528, "p50_ms": 4.1, "p90_ms": 9.0, "p99_ms": 20.2, "fps": 8.79},
        "observation": {"n": 354, "p50_ms": 203.3, "p90_ms": 303.7, "p99_ms": 417.4, "fps": 5.89},
        "semantic": {"n": 354, "p50_ms": 334.4, "p90_ms": 955.6, "p99_ms": 1296.8, "fps": 5.89},
        "map": {"n": 277, "p50_ms": 258.9, "p90_ms": 508.0, "p99_ms": 1055.7, "fps": 4.61},
    },
    "cpu_percent_by_process": {
        "sim-0": {"physics": 22.2, "render": 13.3, "tx": 7.2, "llvmpipe": 6.1, "rx": 4.9,
                  "acc": 2.7},
        "perception-0": {"work": 26.0, "python": 1.2},
        "scene_memory-0": {"on_frame": 25.5, "on_observation": 23.1, "python": 1.1},
        "nbv-0": {"rx": 1.1},
        "gaze-0": {"on_imu": 23.6, "rx": 6.3, "tx": 4.5, "net": 2.8, "python": 1.8,
                   "on_frame": 1.1},
        "router (avs up)": {"rx": 0.8},
        "pipeline meter": {"python": 2.7},
    },
    "cpu_percent_stack": 178.0,
    "duration_s": 60.07,
}  # fmt: skip
PIPELINE_LAST = " ".join(f"{k}={v}" for k, v in PIPELINE["summary"].items())


def test_the_pipeline_renders_its_last_line_stages_and_cpu(tmp_path):
    (tmp_path / "pipeline.json").write_text(json.dumps(PIPELINE))
    text = figures.render_pipeline(f"per stage …\nwrote x\n{PIPELINE_LAST}\n", tmp_path)
    assert text.split("\n") == [
        f"`{PIPELINE_LAST}`",
        "",
        "| stage | frames | fps | p50 ms | p99 ms |",
        "|---|---|---|---|---|",
        "| observation | 354 | 5.89 | 203 | 417 |",
        "| semantic | 354 | 5.89 | 334 | 1297 |",
        "| map | 277 | 4.61 | 259 | 1056 |",
        "",
        "CPU, % of one core over the 60 s: sim 56, scene_memory 50, gaze 40, perception 27, "
        "pipeline meter 3, nbv 1, router (avs up) 1; the stack 178 of the machine's 198",
    ]
    with pytest.raises(RenderError, match=r"pipeline\.json"):
        figures.render_pipeline(PIPELINE_LAST, tmp_path / "nowhere")


SOAK = {  # benchmarks/soak.py --minutes 3 --out DIR, 2026-12-05: its first two minutes
    "minutes": [
        {"minute": 1, "imu_hz": 1000.0, "cmd_head_hz": 968.7, "control_hz": 968.3,
         "frames_hz": 15.0, "observation_hz": 5.98, "scene_updates": 359,
         "gaze_error_deg_p50": 0.181, "gaze_error_deg_p99": 0.508, "restarts": 0,
         "token_flaps": 0, "rss_mb": {"21735": 369.8},
         "cpu_percent": {"sim-0": 53, "perception-0": 22, "scene_memory-0": 22, "nbv-0": 1,
                         "gaze-0": 46, "router (avs up)": 4, "soak meter": 3, "garbage": 3}},
        {"minute": 2, "imu_hz": 999.6, "cmd_head_hz": 974.1, "control_hz": 974.2,
         "frames_hz": 14.96, "observation_hz": 6.01, "scene_updates": 358,
         "gaze_error_deg_p50": 0.158, "gaze_error_deg_p99": 0.501, "restarts": 0,
         "token_flaps": 0, "rss_mb": {"21735": 371.0},
         "cpu_percent": {"sim-0": 54, "perception-0": 21, "scene_memory-0": 22, "nbv-0": 2,
                         "gaze-0": 46, "router (avs up)": 4, "soak meter": 3, "garbage": 3}},
    ],
    "summary": {"minutes": 2},
    "flaps": [],
    "cpu_percent": {
        "sim-0": {"physics": 22.9, "render": 11.7, "tx": 5.2, "llvmpipe": 5.2, "rx": 4.8,
                  "acc": 2.3, "python": 1.8},
        "perception-0": {"work": 19.4, "python": 2.3, "rx": 0.7},
        "scene_memory-0": {"on_frame": 12.0, "on_observation": 9.3, "rx": 0.9},
        "nbv-0": {"rx": 1.3, "net": 0.5},
        "gaze-0": {"on_imu": 23.4, "on_frame": 9.3, "rx": 5.9, "tx": 4.0, "net": 2.5,
                   "python": 1.9},
        "router (avs up)": {"rx": 1.9, "tx": 1.4, "acc": 0.6},
        "soak meter": {"python": 2.3, "rx": 0.9},
        "garbage": {"python": 2.6, "tx": 0.8},
    },
}  # fmt: skip
SOAK_LAST = (
    "minutes=2 imu_hz_min=999.6 cmd_head_hz_min=968.7 observation_hz_min=5.98 "
    "scene_updates_per_min_min=358 token_flaps=0 restarts=0 rss_growth_mb=1.2 "
    "gaze_error_deg_p99=0.503 reference_perception_ms=22.8"
)
SOAK_STDOUT = f"minute 1: IMU 1000.0 Hz …\nwhere the cores go …\n  sim-0: 54 (…)\n{SOAK_LAST}\n"


def test_the_soak_renders_its_minutes_last_line_and_cores(tmp_path):
    (tmp_path / "soak.json").write_text(json.dumps(SOAK))
    minutes, last, cores = figures.render_soak(SOAK_STDOUT, tmp_path).split("\n\n")
    assert minutes.split("\n") == [
        "| minute | IMU Hz | control steps Hz | cmd/head Hz | frames Hz | observations Hz | "
        "scene updates | gaze error p50 / p99 ° | perception % CPU |",
        "|---|---|---|---|---|---|---|---|---|",
        "| 1 | 1000 | 968 | 969 | 15.0 | 5.98 | 359 | 0.18 / 0.51 | 22 |",
        "| 2 | 1000 | 974 | 974 | 15.0 | 6.01 | 358 | 0.16 / 0.50 | 21 |",
    ]
    assert last == f"`{SOAK_LAST}`"
    assert cores.split("\n") == [
        "| process | % of one core | its threads |",
        "|---|---|---|",
        "| sim | 54 | physics 23, render 12, tx 5, llvmpipe 5, rx 5, acc 2 |",
        "| gaze | 47 | on_imu 23, on_frame 9, rx 6, tx 4, net 2, python 2 |",
        "| perception | 22 | work 19, python 2, rx 1 |",
        "| scene_memory | 22 | on_frame 12, on_observation 9, rx 1 |",
        "| router (avs up) | 4 | rx 2, tx 1, acc 1 |",
        "| garbage | 3 | python 3, tx 1 |",
        "| soak meter | 3 | python 2, rx 1 |",
        "| nbv | 2 | rx 1, net 0 |",
    ]


def test_generalization_renders_its_last_line_and_its_markdown_table(tmp_path):
    rows = [
        {"seed": 1000, "objects": 5, "arrangements": ["stack:a,b", "single:c", "hidden:d"],
         "facing_away": False, "crashed": False, "views": 3, "f1_view1": 0.75, "f1_final": 1.0,
         "precision_final": 1.0, "recall_final": 1.0, "inlier_index": 0.731,
         "pose_error_mm": 53.2, "registered": 2},
        {"seed": 1001, "objects": 4, "arrangements": ["single:a", "single:b", "touching:c,d"],
         "facing_away": True, "crashed": True, "errors": ["explore: boom"]},
    ]  # fmt: skip
    (tmp_path / "generalization.json").write_text(json.dumps({"rows": rows}))
    last = "scenes=2 crashed=1 ended_at_view1=1 f1_view1_mean=0.375 f1_final_mean=0.500"
    text = figures.render_generalization(f"seed …\nwrote …\n{last}\n", tmp_path)
    assert text.split("\n")[0] == f"`{last}`"
    assert text.split("\n")[4:] == [
        "| 1000 | 5 | stack, single, hidden | facing | 3 | 0.75 | 1.00 | 1.00 | 1.00 | 0.73 | "
        "53 mm | 2/2 |",
        "| 1001 | 4 | 2× single, touching | away | crashed | | | | | | | |",
    ]


def episode(f1: list[float], fusion: str = "sg", **final) -> dict:
    views = [{"support_f1": x, "unknown_voxels": 5_000_000, "accumulated_path_cost": 10.0}
             for x in f1]  # fmt: skip
    views[-1] |= final
    return {"fusion": fusion, "views": views}


def test_the_fusion_modes_render_f1_median_and_range_per_strategy_and_mode(tmp_path):
    runs = {
        "utility/pc": [episode([0.67, 1.0, 1.0, 1.0], "pc")] * 3,
        "utility/sg": [episode([0.67, 1.0, 0.89, 0.89], "sg"), episode([0.67, 1.0], "sg"),
                       episode([0.67, 0.67, 1.0, 0.8], "sg")],
        "random/pc": [episode([0.67] * 6, "pc"), episode([0.67, 1.0] * 2, "pc"),
                      episode([1.0] * 8, "pc")],
        "random/sg": [episode([0.67] * 6, "sg"), episode([0.67, 1.0] * 2, "sg"),
                      episode([1.0] * 8, "sg")],
    }  # fmt: skip
    expected = [
        "| final support F1, median (min-max) of 3 seeds | `pc` | `sg` | views taken |",
        "|---|---|---|---|",
        "| utility | 1.00 (1.00-1.00) | 0.89 (0.80-1.00) | `pc` 4, 4, 4; `sg` 4, 2, 4 |",
        "| random | 1.00 (0.67-1.00) | 1.00 (0.67-1.00) | 6, 4, 8 |",
    ]
    for data in (runs, {"runs": runs, "summary": {}, "orderings": []}):  # before/after ci95
        (tmp_path / "metrics.json").write_text(json.dumps(data))
        assert figures.render_fusion_modes("", tmp_path).split("\n") == expected


BOOTH_SUMMARY = {  # avs compare --scene booth … --seeds 10 (branch belief), 2026-12-05 02:17
    "utility": {
        "support_f1": {"median": 0.3636, "ci95": [0.3636, 0.4318], "n": 10},
        "unknown_voxels": {"median": 4311314.5, "ci95": [4294203.0, 4327461.5], "n": 10},
        "accumulated_path_cost": {"median": 20.322, "ci95": [19.128, 21.898], "n": 10},
    },
    "occupancy": {
        "support_f1": {"median": 0.5, "ci95": [0.3333, 0.5], "n": 10},
        "unknown_voxels": {"median": 4232692.5, "ci95": [4225774.0, 4239641.5], "n": 10},
        "accumulated_path_cost": {"median": 28.300, "ci95": [27.968, 29.096], "n": 10},
    },
    "random": {
        "support_f1": {"median": 0.3636, "ci95": [0.2, 0.5], "n": 10},
        "unknown_voxels": {"median": 4445648.5, "ci95": [4397302.0, 4600044.0], "n": 10},
        "accumulated_path_cost": {"median": 22.723, "ci95": [16.382, 25.726], "n": 10},
    },
}
BOOTH_ORDERINGS = [
    ("support_f1", "occupancy", "random", False), ("support_f1", "occupancy", "utility", False),
    ("support_f1", "random", "utility", False), ("unknown_voxels", "occupancy", "utility", True),
    ("unknown_voxels", "occupancy", "random", True), ("unknown_voxels", "utility", "random", True),
    ("accumulated_path_cost", "utility", "random", False),
    ("accumulated_path_cost", "utility", "occupancy", True),
    ("accumulated_path_cost", "random", "occupancy", True),
]  # fmt: skip


def test_the_strategies_render_medians_intervals_and_supported_orderings(tmp_path):
    f1 = {"utility": [0.364, 0.364, 0.5, 0.5, 0.364, 0.333, 0.364, 0.364, 0.364, 0.364],
          "occupancy": [0.333, 0.5, 0.333, 0.5, 0.5, 0.5, 0.333, 0.364, 0.615, 0.5],
          "random": [0.364, 0.364, 0.5, 0.5, 0.2, 0.5, 0.333, 0.364, 0.167, 0.2]}  # fmt: skip
    runs = {k: [episode([0.1] * 4 + [x]) for x in v] for k, v in f1.items()}
    orderings = [dict(zip(("metric", "better", "worse", "supported"), o, strict=True))
                 for o in BOOTH_ORDERINGS]  # fmt: skip
    data = {"runs": runs, "summary": BOOTH_SUMMARY, "orderings": orderings}
    (tmp_path / "metrics.json").write_text(json.dumps(data))
    table, orders = figures.render_strategies("", tmp_path).split("\n\n")
    assert table.split("\n") == [
        "| median [95 % interval], 10 seeds | support F1 | unknown voxels, M | path cost, s "
        "| views |",
        "|---|---|---|---|---|",
        "| utility | 0.36 [0.36, 0.43] | 4.31 [4.29, 4.33] | 20.3 [19.1, 21.9] | 5 |",
        "| occupancy | 0.50 [0.33, 0.50] | 4.23 [4.23, 4.24] | 28.3 [28.0, 29.1] | 5 |",
        "| random | 0.36 [0.20, 0.50] | 4.45 [4.40, 4.60] | 22.7 [16.4, 25.7] | 5 |",
    ]
    assert orders == (
        "Orderings the intervals support (apart): unknown voxels: occupancy < utility, "
        "occupancy < random, utility < random; path cost: utility < occupancy, random < "
        "occupancy. Not resolved (they overlap): support F1: occupancy > random, occupancy > "
        "utility, random = utility; path cost: utility < random."
    )
    # the format before the bootstrap: the episodes alone, medians and ranges, said so
    (tmp_path / "metrics.json").write_text(json.dumps(runs))
    table, note = figures.render_strategies("", tmp_path).split("\n\n")
    assert table.split("\n")[0].startswith("| median (min-max), 10 seeds | support F1 |")
    assert table.split("\n")[4] == "| random | 0.36 (0.17-0.50) | 5.00 (5.00-5.00) | 10.0 " \
                                   "(10.0-10.0) | 5 |"  # fmt: skip
    assert "no bootstrap intervals" in note


def test_the_gaze_exposure_renders_the_localised_shares(tmp_path):
    def mode(off_cup, off_box):
        return {"off": {"localization_success": {"cup": off_cup, "textured": off_box},
                        "config": {"sensors": True}},
                "on": {"localization_success": {"cup": 1.0, "textured": 1.0}},
                "flow_decrease": 0.93}  # fmt: skip

    data = {"fixed": mode(0.4092, 0.0264), "auto": mode(0.4092, 0.0132)}
    (tmp_path / "metrics.json").write_text(json.dumps(data))
    assert figures.render_gaze_exposure("", tmp_path).split("\n") == [
        "| localised (sensor models on) | unstabilised | stabilised |",
        "|---|---|---|",
        "| cup, fixed exposure | 41 % | 100 % |",
        "| cup, auto exposure | 41 % | 100 % |",
        "| textured box, fixed exposure | 2.6 % | 100 % |",
        "| textured box, auto exposure | 1.3 % | 100 % |",
    ]


def test_grasping_renders_table_5_1s_layout(tmp_path):
    """Five seeds each way (branch grasp, 2026-12-05): one unstabilised run did not grasp, and
    one stabilised run neither grasped nor met the acuity."""

    def run(grasped, raised, reached, std, mean, max_, all_mean):
        return {"grasped": grasped, "acuity_raised_s": raised, "acuity_reached_s": reached,
                "flow_rmse_deg_s": {"mean": mean, "std": std, "max": max_},
                "flow_rmse_all_deg_s": {"mean": all_mean, "std": 0.0, "max": 0.0},
                "config": {"acuity_grasp": 0.002}}  # fmt: skip

    data = {
        "unstabilised": [
            run(True, 10.3, 10.8, 3.18, 3.40, 16.17, 3.97),
            run(True, 10.2, 10.9, 3.11, 3.38, 9.88, 4.00),
            run(True, 10.3, 10.8, 3.20, 3.37, 15.04, 4.01),
            run(False, 10.3, 10.9, 3.17, 2.37, 17.92, 3.06),
            run(True, 10.3, 10.8, 3.18, 3.37, 14.72, 3.95),
        ],
        "stabilised": [
            run(True, 10.3, 10.66, 1.51, 1.58, 10.68, 2.78),
            run(True, 10.3, 10.66, 1.62, 1.61, 14.57, 2.80),
            run(True, 10.35, 10.69, 1.58, 1.59, 13.64, 2.84),
            run(False, 10.25, None, 1.32, 1.69, 9.62, 2.42),
            run(True, 10.3, 10.66, 1.58, 1.62, 12.36, 2.85),
        ],
    }
    (tmp_path / "metrics.json").write_text(json.dumps(data))
    assert figures.render_grasping("", tmp_path).split("\n") == [
        "| Table 5.1 layout, medians of 5 seeds | unstabilised | stabilised | decrease | "
        "thesis (real robot) |",
        "|---|---|---|---|---|",
        "| flow RMSE std, deg/s | 3.18 | 1.58 | −50.3 % | −49.1 % |",
        "| flow RMSE mean, deg/s | 3.37 | 1.61 | −52.2 % | −51.0 % |",
        "| flow RMSE max, deg/s | 15.04 | 12.36 | −17.8 % | −67.5 % |",
        "| mean with the gaze shifts, deg/s | 3.97 | 2.80 | −29.5 % |  |",
        "| cup grasped | 4 of 5 | 4 of 5 |  |  |",
        "| cup's σ meets the raised acuity (2 mm), s after the raise | 0.5-0.7 (median 0.5) | "
        "0.3-0.4 (median 0.4; never in 1) |  |  |",
    ]
