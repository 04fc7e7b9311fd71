"""The version is importable alone and is the one pyproject.toml declares."""

from __future__ import annotations

import re

from repo_paths import ROOT

from spinemocap.version import __version__


def test_the_version_is_a_release_number_and_pyproject_agrees():
    assert re.fullmatch(r"\d+\.\d+\.\d+", __version__)
    declared = re.search(r'^version\s*=\s*"([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M)
    assert declared is not None and declared.group(1) == __version__
