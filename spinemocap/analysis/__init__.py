"""Spine geometry, angles, batch processing and study reports.

Pipeline: marker table -> :mod:`curve` (row centres, midline spline, tangents) ->
:mod:`levels` (tape rows <-> vertebrae) -> :mod:`frames` (segment and pelvis frames) ->
:mod:`angles` (lumbar/thoracic flexion, lateral bending, axial rotation, lordosis/kyphosis) ->
:mod:`batch` (every trial of a study, local pool or Dask cluster) -> :mod:`report` (HTML, CSV,
XLSX).
"""
