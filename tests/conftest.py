"""Test configuration: in CI (the CI variable is set), hypothesis draws the same examples on every run, so a red
CI always means a changed result, never a newly drawn example; run the tests locally to explore new ones."""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
