"""Test configuration.

In CI (the CI variable is set), hypothesis draws the same examples on every run, so a red CI always means a changed
result, never a newly drawn example; run the tests locally to explore new ones.

Fixture ``shared_data``: the shared data folder of real measurements (``pigments/``, ``paints/``; see its
README.md), ``$KMPIPE_SHARED_DATA`` when set, else ``../shared/data`` beside the repository root. A test that needs it
fails, naming the folder, when it is missing: it is never skipped.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import simulation
from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared data folder (see the module docstring)."""
    try:
        return simulation.shared_data()
    except FileNotFoundError as missing:
        message = str(missing)
    pytest.fail(message, pytrace=False)  # outside the handler: the message alone, no chained traceback
