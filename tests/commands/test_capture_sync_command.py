"""``spinemocap capture sync``: impossible search windows are refused before the capture is read."""

from __future__ import annotations

import pytest

from spinemocap.commands import capture_sync as sync_command
from spinemocap.fileio import InputError


@pytest.mark.parametrize("flag", ["--seconds", "--max-offset"])
def test_a_search_window_that_is_not_positive_is_refused(flag, parse, tmp_path):
    args = parse("capture", "sync", tmp_path / "no-capture", flag, "0")
    assert args.func is sync_command.run_sync
    with pytest.raises(InputError, match="--seconds and --max-offset must be positive"):
        sync_command.run_sync(args)


def test_a_folder_without_a_capture_is_refused_naming_it(parse, tmp_path):
    with pytest.raises(InputError, match="no-capture"):
        sync_command.run_sync(parse("capture", "sync", tmp_path / "no-capture", "--no-progress"))
