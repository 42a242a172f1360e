"""The README's promises: two quick-start commands, CI runs the test one, and the outside
subscriber example works against a live publisher."""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys

import zenoh

from schemas import Keys, encode
from tests.conftest import ROOT, session_config
from tests.streams import rgbd_frame

README = (ROOT / "README.md").read_text()
ARCHITECTURE = (ROOT / "docs" / "architecture.md").read_text()  # the outside subscriber's example


def _quick_start_commands() -> list[str]:
    section = README.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line.split("#", 1)[0].strip() for line in block.splitlines() if line.strip()]


def test_the_readme_is_short_and_opens_with_what_avs_is_and_the_quick_start():
    lines = README.split("\n")
    assert len(lines) <= 300, len(lines)
    headers = [line for line in lines if line.startswith("## ")]
    assert headers[0] == "## Quick start", headers
    assert "AVS lets a humanoid robot" in README.split("## Quick start")[0]
    assert "runs/explore/report.html" in README  # where the results go


def test_every_relative_link_of_the_readme_and_the_docs_names_a_file_that_exists():
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    assert len(docs) >= 6
    broken = []
    for doc in docs:
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if re.match(r"(https?:|#|mailto:)", target):
                continue
            if not (doc.parent / target.split("#", 1)[0]).exists():
                broken.append(f"{doc.relative_to(ROOT)}: {target}")
    assert not broken, broken


def test_quick_start_has_exactly_two_commands_that_exist():
    commands = _quick_start_commands()
    assert commands == ["scripts/run", "scripts/test"]
    for command in commands:
        path = ROOT / command
        assert path.is_file() and path.stat().st_mode & 0o111, command


def test_ci_runs_the_readme_test_command_and_nothing_else():
    lines = [
        line.strip()
        for line in (ROOT / ".ci/run").read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert lines[-1] == "exec scripts/test"
    assert all(line.startswith(("set ", "cd ")) for line in lines[:-1])


def _example() -> str:
    after = ARCHITECTURE.split("<!-- example: external-subscriber -->", 1)[1]
    return re.search(r"```python\n(.*?)```", after, re.S).group(1)


def test_external_subscriber_example_runs_against_a_live_publisher(router, tmp_path):
    example = _example()
    assert "import schemas" not in example and "import services" not in example
    subprocess.run(
        [sys.executable, "-m", "avs.cli", "schema", "export", str(tmp_path / "avs-schemas")],
        check=True,
        cwd=ROOT,
        capture_output=True,
        timeout=60,
    )
    (tmp_path / "example.py").write_text(example)
    env = {"AVS_ROUTER": router, "PATH": "/usr/bin:/bin"}
    reader = subprocess.Popen(
        [sys.executable, "example.py"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    frames = [rgbd_frame(i, 64, 48) for i in range(5)]
    with zenoh.open(session_config("client", connect=[router])) as session:
        publisher = session.declare_publisher(
            Keys().rgbd("head_rgbd"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        i = 0
        while reader.poll() is None and i < 2000:  # publish until the example has read 10
            frame = frames[i % 5].model_copy(update={"seq": i})
            publisher.put(encode(frame))
            i += 1
            with contextlib.suppress(subprocess.TimeoutExpired):
                reader.wait(0.05)
    out, err = reader.communicate(timeout=30)
    assert reader.returncode == 0, err
    lines = out.splitlines()
    assert len(lines) == 10
    _seq, camera, *_ = lines[0].split()
    assert camera == "head_rgbd" and "(48, 64)" in lines[0]
