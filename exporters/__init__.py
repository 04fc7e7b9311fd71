"""Marker writers and readers: TRC (OpenSim), C3D (Vicon Nexus & co), tables, and a plugin
registry (entry-point group ``spinemocap.exporters``). Depends only on :mod:`spinemocap.markers`."""
