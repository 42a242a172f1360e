"""The compiled kernels' cache is keyed by every kernel source: numba checks a cached kernel
only against its own file, so a change to a helper it inlines from another file must move the
cache (it once ran a stale hash function against a rebuilt table and matched nothing)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import services
from services import numba_cache_dir


def test_a_change_to_any_kernel_source_moves_the_cache(tmp_path: Path):
    (tmp_path / "a").mkdir()
    helper = tmp_path / "a" / "helper.py"
    helper.write_text("from numba import njit\n\n@njit\ndef find(k):\n    return k\n")
    (tmp_path / "user.py").write_text("from numba import njit\nfrom a.helper import find\n")
    plain = tmp_path / "plain.py"
    plain.write_text("x = 1\n")
    first = numba_cache_dir(tmp_path)
    plain.write_text("x = 2\n")  # no kernel in it: the cache stays
    assert numba_cache_dir(tmp_path) == first
    helper.write_text(helper.read_text().replace("return k", "return k + 1"))
    assert numba_cache_dir(tmp_path) != first


@pytest.mark.parametrize("first", ["services", "numba"])
def test_the_services_use_it_whatever_was_imported_first(first):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    code = f"import {first}, services, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, cwd=Path(services.__file__).parent.parent)  # fmt: skip
    assert out.stdout.strip() == str(numba_cache_dir())
