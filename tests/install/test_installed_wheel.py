"""lads as a user gets it: built as a wheel, installed (not editable) into a throwaway venv,
run from an empty folder, so nothing can come from the checkout.

The venv borrows the third-party dependencies of the test environment (a `.pth` line naming
its site-packages; the editable install's finder there is not activated by it) instead of
downloading them again: what is under test is lads' own packaging, whose dependency list
`make install` already resolves.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
# What pyproject.toml builds the wheel from.
WHEEL_SOURCES = ("pyproject.toml", "README.md", "LICENSE", "lads", "pipelines", "manifests",
                 "dataset_cards")  # fmt: skip
VARIANTS = ("snow", "rain", "fog", "intensity-kitti", "intensity-nuscenes")
# What the code reads at run time; each must be inside the wheel, under lads/.
PACKAGED = (
    "lads/pipelines/snow.yaml", "lads/pipelines/voxelscape-fog.yaml",
    "lads/pipelines/train/synth-to-kitti.yaml", "lads/manifests/semantickitti.yaml",
    "lads/dataset_cards/template.md", "lads/sensors/hdl64e.yaml", "lads/physics/materials.yaml",
    "lads/intensity/weights/weather.pt", "lads/intensity/weights/weather.md",
    "lads/synth/nuscenes_lidarseg.yaml",
)  # fmt: skip


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel, built from a clean copy of what it is made of (a build/ folder left in the
    checkout would otherwise carry deleted modules into it)."""
    src, dist = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("dist")
    for name in WHEEL_SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(REPO / name, src / name)
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--wheel-dir",
            str(dist),
            str(src),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    (found,) = dist.glob("lads-*.whl")
    return found


@pytest.fixture(scope="module")
def venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv with the wheel installed non-editable; returns its bin/ folder."""
    root = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root)], check=True)
    python = root / "bin" / "python"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--quiet",
            "--no-deps",
            str(wheel),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    deps = sysconfig.get_paths()["purelib"]
    (Path(purelib) / "lads_test_dependencies.pth").write_text(deps + "\n")
    return root / "bin"


def lads(bin_dir: Path, cwd: Path, *args: str, ok: tuple[int, ...] = (0,)) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LADS_DATA")}
    done = subprocess.run(
        [str(bin_dir / "lads"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode in ok, f"lads {' '.join(args)}: {done.returncode}\n{done.stderr}"
    return done.stdout + done.stderr


def test_the_wheel_carries_every_runtime_resource_and_the_licence(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [p for p in PACKAGED if p not in names]
    assert not missing, missing
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert not any(n.startswith(("tests/", "benchmarks/", "pipelines/")) for n in names)


def test_the_installed_package_is_not_the_checkout(venv: Path, tmp_path: Path) -> None:
    out = subprocess.run(
        [
            str(venv / "python"),
            "-c",
            "import lads, lads.resources as r; print(lads.__file__); print(r.pipelines_dir())",
        ],
        cwd=tmp_path,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    assert all(str(REPO) not in line and "site-packages" in line for line in out), out


def test_demo_from_an_empty_folder(venv: Path, tmp_path: Path) -> None:
    said = lads(venv, tmp_path, "demo", "--out", "demo", "--frames", "2")
    assert "verify" in said
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert all(v["verify_ok"] and v["complete"] for v in summary["variants"].values())


def test_synth_then_every_variant_builds_and_verifies(venv: Path, tmp_path: Path) -> None:
    lads(venv, tmp_path, "synth", "--frames", "2", "--out", "syn")
    for variant in VARIANTS:  # each reads its own pipeline and, for most, shipped weights
        lads(
            venv,
            tmp_path,
            "build",
            "--source",
            "semantickitti",
            "--variant",
            variant,
            "--in",
            "syn",
            "--out",
            f"syn-{variant}",
            "--no-figures",
        )
    lads(venv, tmp_path, "verify", "syn-snow", "--against", "syn", "--regenerate", "2")
    run = json.loads((tmp_path / "syn-snow" / "run.json").read_text())
    assert run["git_commit"] is None  # an installed lads records its version only
    assert run["lads_version"] and (tmp_path / "syn-snow" / "README.md").is_file()
    lads(venv, tmp_path, "card", "syn-intensity-kitti")
    lads(venv, tmp_path, "verify", "syn-intensity-kitti", "--against", "syn")


@pytest.mark.parametrize("layout", ["nuscenes", "voxelscape"])
def test_other_layouts_build_their_own_pipelines(venv: Path, tmp_path: Path, layout: str):
    # nuScenes: the devkit walks the tables, the weather model writes HDL-32E integers;
    # Voxelscape: its source-specific physics-only pipeline.
    lads(venv, tmp_path, "synth", "--layout", layout, "--frames", "2", "--out", "syn")
    lads(
        venv,
        tmp_path,
        "build",
        "--source",
        layout,
        "--variant",
        "snow",
        "--in",
        "syn",
        "--out",
        "snow",
        "--no-figures",
    )
    lads(venv, tmp_path, "verify", "snow", "--against", "syn", "--regenerate", "1")


def test_verify_finds_the_shipped_inventories(venv: Path, tmp_path: Path) -> None:
    lads(venv, tmp_path, "synth", "--frames", "1", "--out", "syn")
    lads(
        venv,
        tmp_path,
        "build",
        "--source",
        "semantickitti",
        "--variant",
        "rain",
        "--in",
        "syn",
        "--out",
        "rain",
        "--no-figures",
    )
    said = lads(venv, tmp_path, "verify", "rain", "--inventory", "semantickitti-00-10", ok=(1,))
    assert "incomplete_release" in said and "no inventory" not in said


def test_listings(venv: Path, tmp_path: Path) -> None:
    assert "intensity-nuscenes" in lads(venv, tmp_path, "variants")
    assert "hdl32e" in lads(venv, tmp_path, "profiles")
    said = lads(
        venv,
        tmp_path,
        "build",
        "--source",
        "nuscenes",
        "--variant",
        "hail",
        "--in",
        ".",
        "--out",
        "x",
        ok=(2,),
    )
    assert "variants of 'nuscenes': fog, intensity-kitti" in said


def test_train_and_evaluate_a_user_config(venv: Path, tmp_path: Path) -> None:
    """A config of the user's own, next to their data; outputs go to the working folder."""
    lads(venv, tmp_path, "synth", "--frames", "3", "--out", "data/target", "--seed", "4")
    config = {
        "schema_version": 1, "name": "mine", "kind": "sensor",
        "pairs": {"kitti": {
            "source": {"dataset": "synth", "sensor": "hdl64e", "frames": 2, "seed": 1},
            "target": {"dataset": "semantickitti", "root": "target",
                       "split": {"train": ["sequences/00/velodyne/00000[01].bin"],
                                 "test": ["sequences/00/velodyne/000002.bin"]}},
        }},
        "steps": 2, "base": 4, "blocks": 1, "batch": 1, "crop_width": 64, "workers": 1,
    }  # fmt: skip
    (tmp_path / "data" / "mine.yaml").write_text(yaml.safe_dump(config))
    lads(venv, tmp_path, "train", "data/mine.yaml")
    weights = tmp_path / "runs" / "mine" / "mine.pt"
    assert weights.is_file()
    lads(
        venv,
        tmp_path,
        "eval-intensity",
        "data/mine.yaml",
        "--model",
        str(weights),
        "--out",
        "eval",
        "--no-figures",
    )
    result = json.loads((tmp_path / "eval" / "eval.json").read_text())["kitti"]
    assert "generator" in result["methods"] and result["frames"] == [
        "sequences/00/velodyne/000002.bin"
    ]


def test_train_and_evaluate_a_shipped_config_on_real_data(
    venv: Path, tmp_path: Path, shared_data: Path
) -> None:
    lads(
        venv,
        tmp_path,
        "train",
        "synth-to-kitti",
        "--data-root",
        str(shared_data),
        "--steps",
        "2",
        "--jobs",
        "1",
    )
    weights = tmp_path / "runs" / "synth-to-kitti" / "synth-to-kitti.pt"
    assert weights.is_file()
    lads(
        venv,
        tmp_path,
        "eval-intensity",
        "synth-to-kitti",
        "--data-root",
        str(shared_data),
        "--out",
        "eval",
        "--no-figures",
    )
    assert (tmp_path / "eval" / "eval.json").is_file()
