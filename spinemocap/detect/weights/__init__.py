"""Shipped network weights and how each set was produced (the ``.json`` beside it): the default
``tape_unet_lab_mix.pt`` (studio renders and the lab mix) and ``tape_unet.pt`` (studio renders
alone). A package so that setuptools ships the files as package data."""
