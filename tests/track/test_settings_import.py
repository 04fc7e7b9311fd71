"""Importing the tracker's settings stays light: no torch, no Pyomo, no SciPy (a config file can be
read, checked and written by tools that never run the tracker)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from repo_paths import ROOT

HEAVY = ("torch", "pyomo", "scipy", "cv2")
PROBE = """
import json, sys, time
start = time.perf_counter()
from spinemocap.track.config import TrackerConfig
TrackerConfig.from_dict(TrackerConfig().to_dict())
print(json.dumps({"seconds": time.perf_counter() - start,
                  "heavy": sorted({m.split('.')[0] for m in sys.modules} & set(%r))}))
"""


def test_tracker_config_imports_no_heavy_library():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", PROBE % (HEAVY,)], env=env, cwd=ROOT,
                         capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"import spinemocap.track.config + a round trip: {result['seconds']:.3f} s")
    assert result["heavy"] == [], f"importing TrackerConfig loaded {result['heavy']}"
