"""The application layer: what a user runs, built from the core types and the domain packages.

:mod:`~spinemocap.app.run` tracks a capture folder end to end (``spinemocap track``, the demo),
:mod:`~spinemocap.app.batch` processes a study (``spinemocap batch``). Benchmarks live beside it in
:mod:`spinemocap.bench`, the CLI commands in :mod:`spinemocap.commands`. See docs/ARCHITECTURE.md.
"""
