"""A lab's own marker format, plugged into spinemocap through the ``spinemocap.exporters``
entry-point group only (tests/exporters/test_export_plugin.py installs it as a distribution on sys.path).

It deliberately does not subclass :class:`exporters.Exporter` and writes straight to the path it
is given: the registry still makes the write atomic. Format: JSON with labels, fps and per-frame
positions in metres (null for missing).
"""

import json
import math

import numpy as np

from spinemocap.markers import MarkerTable


class LabJsonExporter:
    name = "labjson"
    extensions = (".labjson",)
    description = "Example lab format: JSON, metres"

    def write(self, table, path, indent=None):
        arrays = table.to_arrays()
        frames = [[None if not np.isfinite(p).all() else [float(v) / 1000.0 for v in p] for p in row]
                  for row in arrays.positions]
        doc = {"labels": [str(l) for l in arrays.labels], "fps": table.fps, "first_frame": int(arrays.frames[0]),
               "frames": frames}
        with open(path, "w") as handle:
            if table.meta.get("explode_after_half"):  # lets a test make the write fail midway
                handle.write(json.dumps(doc)[:10])
                raise OSError("simulated disk full")
            json.dump(doc, handle, indent=indent)

    def read(self, path):
        with open(path) as handle:
            doc = json.load(handle)
        nan3 = [math.nan] * 3
        positions = np.array([[nan3 if p is None else p for p in row] for row in doc["frames"]], float) * 1000.0
        return MarkerTable.from_arrays(doc["labels"], positions, fps=doc["fps"], first_frame=doc["first_frame"])
