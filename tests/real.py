"""Where the real RGB-D recordings are (``AVS_REAL_DATA``, else ``../shared/data/real`` beside
the checkout) and the mark that skips a test without them, saying where they come from."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.conftest import ROOT

REAL = Path(os.environ.get("AVS_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
needs_real = pytest.mark.skipif(
    not (REAL / "redkitchen-a").is_dir() or not (REAL / "fetch-table").is_dir(),
    reason=f"the real recordings are not at {REAL} (7-Scenes redkitchen, Microsoft Research; "
    "HRT1 fetch-table, UT Dallas: see that folder's README.md)",
)
