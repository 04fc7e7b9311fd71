"""Sub-commands of the ``spinemocap`` CLI, one module each (see :mod:`spinemocap.cli`)."""
