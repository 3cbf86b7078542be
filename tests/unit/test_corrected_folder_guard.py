"""`--write-corrected` replaces only its own earlier output, never a user's folder."""

from __future__ import annotations

import pytest

from lads.diagnose.output.corrected import _clear_previous
from lads.errors import DiagnoseError


def _tree(root, names):
    for name in names:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(b"x")
    return root


def test_an_earlier_corrected_tree_or_an_empty_folder_is_replaced(tmp_path):
    files = ["sequences/00/velodyne/000000.bin", "sequences/00/labels/000000.label"]
    sim = _tree(tmp_path / "sim", files)
    earlier = _tree(tmp_path / "earlier", files)
    _clear_previous(earlier, sim)
    assert not earlier.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    _clear_previous(empty, sim)
    assert not empty.exists()


def test_a_folder_with_anything_else_is_refused_and_left_intact(tmp_path):
    sim = _tree(tmp_path / "sim", ["sequences/00/velodyne/000000.bin"])
    thesis = _tree(tmp_path / "thesis", ["sequences/00/velodyne/000000.bin", "thesis.tex"])
    with pytest.raises(DiagnoseError, match="not an earlier corrected tree"):
        _clear_previous(thesis, sim)
    assert (thesis / "thesis.tex").read_bytes() == b"x"
    (tmp_path / "file").write_bytes(b"y")
    with pytest.raises(DiagnoseError, match="not a folder"):
        _clear_previous(tmp_path / "file", sim)
