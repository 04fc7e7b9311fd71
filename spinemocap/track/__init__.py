"""The tracker: per-view dots -> labelled 3D tape dots.

Stages, one module each, in the order data flows (paper sections 3-3.3):
candidates (triangulation + merging) -> edges (edge cloud) -> lp (edge selection, HiGHS) ->
mrf1 (alignment to the feasible set) -> mrf2 (refinement on the images) -> labels/sequence.
The data passed between stages is defined in :mod:`spinemocap.track.types`.
"""
