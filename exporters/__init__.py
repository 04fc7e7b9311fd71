"""Marker writers and readers: TRC (OpenSim), C3D (Vicon Nexus & co), tables, and a plugin
registry (entry-point group ``spinemocap.exporters``). Depends only on spinemocap's core modules
(:mod:`spinemocap.markers`, :mod:`spinemocap.fileio`), never on the tracker.

    import exporters
    exporters.write(table, "out/markers.trc")                      # format from the extension
    exporters.write(table, "out/markers.trc", units="m", opensim_axes=True)
    exporters.write(table, "out/markers.c3d", reference=ground_truth)
    exporters.write_parts(tables, "out/markers.c3d", n_frames)     # a long table part by part
    table = exporters.read("trial.c3d")
    exporters.available()   # ['c3d', 'csv', 'parquet', 'trc', ...plugins]

Every write goes through a temporary file renamed into place: a failing export leaves the
previous file untouched and no temporary behind.
"""

from .common import ExportWarning
from .registry import ENTRY_POINT_GROUP, Exporter, available, format_for_path, get, read, write, write_parts

__all__ = ["ENTRY_POINT_GROUP", "ExportWarning", "Exporter", "available", "format_for_path", "get", "read",
           "write", "write_parts"]
