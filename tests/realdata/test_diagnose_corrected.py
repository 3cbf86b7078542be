"""`--write-corrected`: the simulated tree with a fitted model applied, in the same format.

The model here is fixed by hand (a gain of e^-1, no effects), so the expected value of every
corrected point is known: round(((i_sim + h) e^-1 - h) / step) step, clipped to the encoding.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from benchmarks.diagnose_cases.generate import generate_case
from lads.diagnose.data.beams import paired_table, unpaired_tables
from lads.diagnose.data.trees import open_trees
from lads.diagnose.fit.from_table import paired_design, unpaired_design
from lads.diagnose.fit.likelihood import Model
from lads.diagnose.fit.model import Fit
from lads.diagnose.output.corrected import write_corrected
from lads.diagnose.selection.select import reference_levels
from lads.errors import DiagnoseError

pytestmark = pytest.mark.realdata
STEP, TOP, H = 0.01, 0.99, 0.005  # SemanticKITTI remission encoding
LN_GAIN = -1.0


def expected(i_sim: np.ndarray) -> np.ndarray:
    value = (i_sim.astype(np.float64) + H) * math.exp(LN_GAIN) - H
    return np.clip(np.round(value / STEP) * STEP, 0.0, TOP).astype(np.float32)


def gain_only(design) -> Fit:
    # Return logit 12: no beam is dropped (there is no dropout effect anyway).
    model = Model([], *reference_levels(design))
    return Fit(model, np.array([LN_GAIN, math.log(0.3), 0.0, 0.0, 12.0]), 0.0, True)


def scans(root: Path) -> dict[str, np.ndarray]:
    return {
        p.relative_to(root).as_posix(): np.fromfile(p, dtype="<f4").reshape(-1, 4)
        for p in sorted(root.rglob("velodyne/*.bin"))
    }


@pytest.fixture(scope="module")
def trees(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A null case whose simulated tree has every 7th point stored at the maximum."""
    root = tmp_path_factory.mktemp("corrected")
    generate_case("K18", "semantickitti", 1, root, mode="M1", max_points=12000)
    for path in (root / "sim").rglob("velodyne/*.bin"):
        pts = np.fromfile(path, dtype="<f4").reshape(-1, 4).copy()
        pts[::7, 3] = TOP
        path.write_bytes(pts.astype("<f4").tobytes())
    return root


def test_every_paired_return_gets_the_fitted_law_including_saturated_ones(
    trees: Path, tmp_path: Path
) -> None:
    pair = open_trees(trees / "sim", trees / "real", "semantickitti", paired=True)
    table = paired_table(pair)
    design = paired_design(table)
    out = tmp_path / "corrected"
    write_corrected(pair, table, design, gain_only(design), out, seed=0)
    sim, corrected = scans(trees / "sim"), scans(out)
    assert sim.keys() == corrected.keys()
    saturated_seen = 0
    for s, rel in enumerate(table.scans):
        rows = table.sim_index[(table.scan == s) & table.ret_sim & (table.sim_index >= 0)]
        before, after = sim[rel][rows, 3], corrected[rel][rows, 3]
        np.testing.assert_allclose(after, expected(before), atol=1e-6)
        saturated_seen += int(np.sum(before == np.float32(TOP)))
        # Geometry is untouched.
        np.testing.assert_array_equal(corrected[rel][:, :3], sim[rel][:, :3])
    # The saturated returns are out of the fit but not out of the corrected tree: the law
    # applied to their stored value brings them from 0.99 to about 0.37.
    assert saturated_seen > 100


def test_an_unpaired_corrected_tree_corrects_every_simulated_return(
    trees: Path, tmp_path: Path
) -> None:
    pair = open_trees(trees / "sim", trees / "real", "semantickitti", paired=False)
    sim_table, real_table = unpaired_tables(pair)
    design = unpaired_design(sim_table, real_table)
    out = tmp_path / "corrected"
    write_corrected(pair, real_table, design, gain_only(design), out, seed=0, sim_table=sim_table)
    sim, corrected = scans(trees / "sim"), scans(out)
    assert sim.keys() == corrected.keys()
    for rel in sim:
        # No dropout is fitted unpaired: every point stays, each with the gain applied.
        assert corrected[rel].shape == sim[rel].shape
        np.testing.assert_allclose(corrected[rel][:, 3], expected(sim[rel][:, 3]), atol=1e-6)
    with pytest.raises(DiagnoseError, match="sim_table"):
        write_corrected(pair, real_table, design, gain_only(design), tmp_path / "again", 0)


def test_the_corrected_tree_may_not_overwrite_an_input(trees: Path, tmp_path: Path) -> None:
    sim = tmp_path / "sim"
    shutil.copytree(trees / "sim", sim)
    pair = open_trees(sim, trees / "real", "semantickitti", paired=True)
    table = paired_table(pair)
    design = paired_design(table)
    with pytest.raises(DiagnoseError, match="input tree"):
        write_corrected(pair, table, design, gain_only(design), sim, seed=0)
