"""Every command that writes a folder says in words when it cannot, before doing the work:
a file in the way of --out, --run-dir or --output gives a named error, not a traceback."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from lads.cli import EXIT_LADS_ERROR, main
from lads.errors import OutputWriteError
from lads.files import make_folder


def test_a_file_in_the_way_of_a_folder_is_named(tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    with pytest.raises(OutputWriteError, match="a part of the path is a file"):
        make_folder(blocker / "run")
    with pytest.raises(OutputWriteError, match="is a file, not a folder"):
        make_folder(blocker)
    make_folder(tmp_path / "a" / "b")
    assert (tmp_path / "a" / "b").is_dir()


@pytest.mark.parametrize(
    "args",
    [
        ["demo", "--out", "{f}"],
        ["demo", "--out", "{f}/demo"],
        ["train", "synth-to-kitti", "--data-root", "{d}", "--run-dir", "{f}/run", "--steps", "1"],
        ["train", "synth-to-kitti", "--data-root", "{d}", "--output", "{f}/x.pt", "--steps", "1"],
        ["eval-intensity", "synth-to-kitti", "--data-root", "{d}", "--out", "{f}/ev"],
    ],
)
def test_commands_refuse_a_file_in_the_way_before_working(tmp_path, args):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    data = tmp_path / "data"  # empty: the commands must stop before reading it
    data.mkdir()
    filled = [a.format(f=blocker, d=data) for a in args]
    result = CliRunner().invoke(main, filled)
    assert result.exit_code == EXIT_LADS_ERROR, result.output
    assert "file" in result.output and "Traceback" not in result.output
