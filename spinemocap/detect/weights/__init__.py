"""Shipped network weights (``tape_unet.pt``) and how they were produced (``tape_unet.json``).
A package so that setuptools ships the files as package data."""
