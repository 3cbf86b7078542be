"""What the wheel is made of: every package and resource the code reads, and the run record
of an installed lads (tests/install/ builds and runs the real wheel)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

import lads
from lads import resources, run_info
from lads.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def test_the_package_list_names_every_package_under_lads_and_the_mapped_folders():
    tool = _pyproject()["tool"]["setuptools"]
    on_disk = {
        ".".join(p.parent.relative_to(REPO).parts)
        for p in (REPO / "lads").rglob("*.py")
        if "__pycache__" not in p.parts
    }
    mapped = {"lads.pipelines": "pipelines", "lads.manifests": "manifests",
              "lads.dataset_cards": "dataset_cards"}  # fmt: skip
    assert tool["package-dir"] == mapped
    expected = on_disk | set(mapped) | {"lads.pipelines.train", "lads.intensity.weights"}
    assert set(tool["packages"]) == expected, sorted(set(tool["packages"]) ^ expected)
    assert all((REPO / folder / "__init__.py").is_file() for folder in mapped.values())


@pytest.mark.parametrize(
    ("folder", "pattern"),
    [("pipelines", "*.yaml"), ("pipelines/train", "*.yaml"), ("manifests", "*.yaml")],
)
def test_package_data_covers_every_shipped_file(folder: str, pattern: str) -> None:
    package = "lads." + folder.replace("/", ".")
    data = _pyproject()["tool"]["setuptools"]["package-data"][package]
    assert pattern in data and list((REPO / folder).glob(pattern))


def test_resources_resolve_to_the_repository_folders_in_a_checkout():
    assert resources.pipelines_dir() == REPO / "pipelines"
    assert resources.train_configs_dir() == REPO / "pipelines" / "train"
    assert resources.manifests_dir() == REPO / "manifests"
    assert resources.card_template() == REPO / "dataset_cards" / "template.md"
    assert resources.weights_dir() == REPO / "lads" / "intensity" / "weights"
    assert (resources.sensors_dir() / "hdl64e.yaml").is_file()


def test_a_missing_resource_package_is_a_config_error():
    with pytest.raises(ConfigError, match="incomplete: reinstall"):
        resources.resource_dir("lads.no_such_resources")


def test_the_licence_is_declared_and_present():
    project = _pyproject()["project"]
    assert project["license"] == "Apache-2.0" and project["license-files"] == ["LICENSE"]
    assert "Apache License" in (REPO / "LICENSE").read_text()
    assert project["requires-python"] == ">=3.11,<3.13"


def test_git_commit_is_recorded_only_for_lads_own_checkout(tmp_path, monkeypatch):
    assert run_info.own_checkout() == REPO  # the tests run from the checkout
    # An installed lads inside some other repository: its package folder has no lads
    # pyproject beside it, so no commit is recorded.
    other = tmp_path / "someone-else" / "venv" / "site-packages" / "lads"
    other.mkdir(parents=True)
    (tmp_path / "someone-else" / ".git").mkdir()
    (other.parent / "pyproject.toml").write_text('[project]\nname = "other"\n')
    monkeypatch.setattr(lads, "__file__", str(other / "__init__.py"))
    assert run_info.own_checkout() is None
    assert run_info.git_commit() is None
