"""Folders the tests read: the repository root and the shared real data beside it.

``SHARED`` is ``$SPINEMOCAP_SHARED`` when set, else ``../shared`` next to the repository; tests
that read it skip when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
SHARED = Path(os.environ.get("SPINEMOCAP_SHARED", ROOT.parent / "shared"))
