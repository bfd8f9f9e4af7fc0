"""Shared fixtures. Data-dependent tests (marked ``data``) read the real data set and fail, not skip, when it
is absent, so a CI run without the data cannot pass silently."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from simshear_gym.data.paths import DATA_ENV, DEFAULT_DATA_ROOT


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = Path(os.environ.get(DATA_ENV, DEFAULT_DATA_ROOT))
    if not (root / "tactip331").is_dir():
        pytest.fail(
            f"real data not found: {root.resolve()}/tactip331 is missing. Data tests need the tactip331 sets; "
            f"set {DATA_ENV} to the folder holding tactip331/ (default {DEFAULT_DATA_ROOT} from the repo root).",
            pytrace=False,
        )
    return root


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Keep the decoded-image cache of tests away from the user's cache."""
    monkeypatch.setenv("SIMSHEAR_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
