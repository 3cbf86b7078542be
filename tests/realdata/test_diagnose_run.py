"""`lads diagnose` end to end: a concealed effect in a generated pair of trees is named and
fitted, a null case is not, the report has its contract, and bad input is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from benchmarks.diagnose_cases.generate import generate_case
from lads.cli import main
from lads.diagnose.effects.catalogue import CATALOGUE
from lads.diagnose.run import diagnose
from lads.diagnose.verdict.analysis import Settings
from lads.errors import DiagnoseError

pytestmark = pytest.mark.realdata
FAST = Settings(fit_rows=4000, resamples=2, bootstrap=6)


@pytest.fixture(scope="module")
def k2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("k2")
    generate_case("K2", "semantickitti", 3, root, mode="M1", max_points=12000)
    return root


def test_a_concealed_attenuation_is_named_and_fitted_within_its_ci(
    k2: Path, tmp_path: Path
) -> None:
    truth = json.loads((k2 / "truth.json").read_text())
    alpha = truth["effects"][0]["params"]["alpha_per_m"]
    doc = diagnose(
        k2 / "sim",
        k2 / "real",
        "semantickitti",
        tmp_path / "out",
        seed=0,
        settings=FAST,
        write_corrected_to=tmp_path / "corrected",
    )
    fitted = {e["id"]: e for e in doc["effects"]}
    assert "C5" in fitted or any("C5" in s["ids"] for s in doc["ambiguity_sets"])
    if "C5" in fitted:
        est = fitted["C5"]["params"]["alpha_per_m"]
        assert abs(est - alpha) < 0.1 * (0.03 - 0.002)
    # The report contract of the issue.
    for key in ("verdict", "localization", "effects", "alternatives", "noise_model", "heldout"):
        assert key in doc
    assert doc["verdict"] in ("effects_found", "no_missing_physics", "ambiguous")
    for e in doc["effects"]:
        assert CATALOGUE[e["id"]].key == e["key"]
        assert set(e["params"]) <= set(e["ci95"])
        assert 0.0 <= e["selection_frequency"] <= 1.0
    held = doc["heldout"]
    assert held["after"]["rmse_ln_i"] < held["before"]["rmse_ln_i"]
    assert {"dropout_brier", "dropout_log_loss", "w1_ln_i_by_class"} <= set(held["after"])
    out = tmp_path / "out"
    assert json.loads((out / "report.json").read_text())["verdict"] == doc["verdict"]
    assert "C5" in (out / "report.md").read_text() or doc["verdict"] == "no_missing_physics"
    assert all((out / f).stat().st_size > 0 for f in doc["figures"])
    # The corrected tree has the simulation's layout and files.
    sim_files = sorted(p.relative_to(k2 / "sim") for p in (k2 / "sim").rglob("*") if p.is_file())
    corr = tmp_path / "corrected"
    assert sorted(p.relative_to(corr) for p in corr.rglob("*") if p.is_file()) == sim_files


def test_a_null_case_claims_no_physics(tmp_path: Path) -> None:
    generate_case("K18", "semantickitti", 5, tmp_path / "case", mode="M1", max_points=12000)
    doc = diagnose(
        tmp_path / "case" / "sim",
        tmp_path / "case" / "real",
        "semantickitti",
        tmp_path / "out",
        seed=0,
        settings=FAST,
    )
    claimed = [e["id"] for e in doc["effects"] if e["status"] == "claimed"]
    assert claimed == []
    assert doc["verdict"] == "no_missing_physics"


def test_trees_that_do_not_correspond_are_refused_with_exit_code_2(
    k2: Path, tmp_path: Path
) -> None:
    real = tmp_path / "real"
    shutil.copytree(k2 / "real", real)
    victim = sorted(real.rglob("*.bin"))[0]
    victim.rename(victim.with_name("999999.bin"))
    result = CliRunner().invoke(
        main,
        [
            "diagnose",
            "--sim",
            str(k2 / "sim"),
            "--real",
            str(real),
            "--source",
            "semantickitti",
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert result.exit_code == 2
    assert "999999" in result.output or "relative" in result.output.lower()


def test_constant_intensities_are_refused(k2: Path, tmp_path: Path) -> None:
    real = tmp_path / "real"
    shutil.copytree(k2 / "real", real)
    for path in real.rglob("*.bin"):
        pts = np.fromfile(path, dtype="<f4").reshape(-1, 4)
        pts[:, 3] = 0.25
        pts.astype("<f4").tofile(path)
    with pytest.raises(DiagnoseError, match="same value"):
        diagnose(k2 / "sim", real, "semantickitti", tmp_path / "out", settings=FAST)


def test_too_few_points_are_refused(tmp_path: Path) -> None:
    generate_case("K18", "semantickitti", 1, tmp_path / "case", mode="M1", max_points=200)
    with pytest.raises(DiagnoseError, match="comparable beams"):
        diagnose(
            tmp_path / "case" / "sim",
            tmp_path / "case" / "real",
            "semantickitti",
            tmp_path / "out",
            settings=FAST,
        )
