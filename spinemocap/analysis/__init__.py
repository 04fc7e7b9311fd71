"""Spine geometry and angles from a marker table.

Pipeline: marker table -> :mod:`curve` (row centres, midline spline, tangents) ->
:mod:`levels` (tape rows <-> vertebrae) -> :mod:`frames` (segment and pelvis frames) ->
:mod:`angles` (lumbar/thoracic flexion, lateral bending, axial rotation,
lordosis/kyphosis). Processing a whole study (local pool or Dask cluster) and
its report (HTML, CSV, XLSX) are the application layer's :mod:`spinemocap.app.batch` and
:mod:`spinemocap.app.report`.
"""
