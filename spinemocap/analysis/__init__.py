"""Spine geometry and angles from a marker table.

Pipeline: marker table -> :mod:`curve` (row centres, midline spline, tangents) ->
:mod:`levels` (tape rows <-> vertebrae) -> :mod:`frames` (segment and pelvis frames) ->
:mod:`angles` (lumbar/thoracic flexion, lateral bending, axial rotation,
lordosis/kyphosis) -> :mod:`neutral` (motion from a neutral posture: flexion / extension from
neutral, ROM) and :mod:`shape` (segmental angles per vertebra pair, the midline in the subject's
sagittal and frontal planes). Processing a whole study (local pool or Dask cluster) and
its report (HTML, CSV, XLSX) are the application layer's :mod:`spinemocap.app.batch` and
:mod:`spinemocap.app.report`.
"""
