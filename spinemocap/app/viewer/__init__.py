"""Seeing what was tracked: labelled camera videos and the tape in 3D in the browser.

- :mod:`.tracked` reads a results folder or marker file into :class:`~.tracked.TrackedDots`
  (positions, each dot's :class:`~.tracked.DotClass`: observed, inferred or flagged) and the
  capture's row-to-level map;
- :mod:`.video` draws the dots, reprojected through the rig with its lens distortion
  (:meth:`spinemocap.camera.Camera.project`), on each camera's own frames and writes one H.264 MP4
  per camera and a grid of all cameras (``spinemocap view``);
- :mod:`.scene3d` writes one self-contained HTML page (no network, no other file) that turns the
  tape, the cameras and the spine's level labels around in 3D with a time slider.
"""
