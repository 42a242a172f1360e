"""The rendered views are shared by every scene memory test module (rendering takes seconds)."""

from __future__ import annotations

import pytest

from tests.scene_memory.views import Update, render_updates


@pytest.fixture(scope="session")
def updates() -> list[Update]:
    return render_updates()
