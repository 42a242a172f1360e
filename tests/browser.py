"""A page as a real browser shows it: headless Chromium loads an HTML file at a set window
width and reports its images (loaded or broken) and how wide the page is laid out."""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

#: run in the page once it has loaded: its images and its width, as JSON in a <pre>
_CHECK = """<script>
window.addEventListener("load", () => {
  const images = [...document.images];
  const out = {
    images: images.length,
    broken: images.filter((i) => !(i.complete && i.naturalWidth > 0)).map((i) => i.alt),
    width: document.documentElement.scrollWidth,
    alts: images.map((i) => i.alt),
  };
  const pre = document.createElement("pre");
  pre.id = "avs-check";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def chromium() -> str:
    """The Chromium binary; skips without one, fails where ``AVS_REQUIRE_CHROMIUM`` is set
    (scripts/test sets it once it has installed Chromium)."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        if os.environ.get("AVS_REQUIRE_CHROMIUM"):
            pytest.fail("AVS_REQUIRE_CHROMIUM is set but there is no chromium on PATH")
        pytest.skip("no chromium: apt-get install chromium (scripts/test does, as root)")
    return browser


def layout(page: Path, tmp: Path, width: int = 1280) -> dict:
    """``page`` loaded by headless Chromium in a window ``width`` px wide: ``images`` (how
    many), ``broken`` (the alt texts of those that did not load), ``width`` (the laid-out
    page's scroll width, px) and ``alts``."""
    probe = page.with_name(page.stem + ".probe.html")
    probe.write_text(page.read_text() + _CHECK)
    try:
        done = subprocess.run(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
             f"--user-data-dir={tmp / 'chromium'}", f"--window-size={width},900",
             "--virtual-time-budget=10000", "--dump-dom", probe.resolve().as_uri()],
            capture_output=True, text=True, timeout=120, check=True,
        )  # fmt: skip
    finally:
        probe.unlink(missing_ok=True)
    m = re.search(r'<pre id="avs-check">(.*?)</pre>', done.stdout, re.S)
    assert m, f"the page's check did not run: {done.stdout[-500:]} {done.stderr[-1000:]}"
    return json.loads(html.unescape(m.group(1)))
