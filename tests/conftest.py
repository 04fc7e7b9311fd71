"""Test-suite root: pytest puts this folder on ``sys.path``, so every test folder imports the
shared helpers beside this file (``repo_paths``, ``tape_scenes``, ``c3d_corpus``, ``fuzzing``,
``lab_recordings``)."""
