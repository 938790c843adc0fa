"""The experiment of paper 001 reproduced (examples/paper001_machine.py) and its uncertainty analysis
(001 §4.4): the Monte Carlo of the multilateration agrees with its linear propagation. Units: mm, µm."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from olti_drake.model.budget import ReadingErrors, paper001_budget
from olti_drake.model.machine import MachineScenario, simulate_machine_campaign
from olti_drake.estimation.multilateration import Multilateration, machine_campaign
from olti_drake.estimation.uncertainty import monte_carlo

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "paper001_machine.py"
FIGURES = ("fig06_07_station_estimation.png", "fig10_targets.png", "fig13_linear_errors.png", "fig14_uncertainty.png")


@pytest.fixture(scope="module")
def solved():
    budget = paper001_budget()
    cols, _ = simulate_machine_campaign(MachineScenario(seed=3), budget)
    ident = Multilateration(machine_campaign(cols))
    return ident, ident.solve(budget), budget


def test_batched_residual_rows_match_the_residuals(solved):
    ident, res, _ = solved
    X = res.fit.x + 1e-3 * np.random.default_rng(0).standard_normal((3, len(res.fit.x)))
    r, cols, vals = ident.residual_rows(X)
    for t in range(3):
        r1, J = ident.residuals(X[t])
        np.testing.assert_allclose(r[t], r1, atol=1e-15)
        dense = np.zeros_like(J.toarray())
        np.add.at(dense, (np.arange(len(r1))[:, None], cols), vals[t])
        np.testing.assert_allclose(dense, J.toarray(), atol=1e-15)


def test_monte_carlo_of_the_multilateration_agrees_with_the_linear_uncertainty(solved):
    ident, res, budget = solved
    mc = monte_carlo(ident, res.fit.x, ReadingErrors(budget), trials=2000, seed=7)
    n = 2 * ident.data.n_targets
    std = mc.samples.std(axis=0, ddof=1)
    # The trials scatter around the estimate (the readings are its own plus budget errors) ...
    assert np.abs(mc.samples.mean(axis=0) - res.fit.x)[:n].max() < 4 * std[:n].max() / np.sqrt(2000)
    # ... as widely as the linear propagation says: the U(k = 2) of Fig. 14 within 10 %.
    u_mc = np.hypot(*std[:n].reshape(-1, 2).T)
    u_lin = np.hypot(*res.targets_std_mm.T)
    assert np.all(np.abs(u_mc / u_lin - 1) < 0.10), (u_mc / u_lin).round(3)
    np.testing.assert_allclose(std[n:], res.fit.std[n:], rtol=0.10)  # stations and dead paths too


def test_example_writes_the_figures_and_a_max_uncertainty_of_the_papers_order(tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLE), "--out", str(tmp_path / "out"), "--trials", "1000"],
                          cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    for name in FIGURES:
        png = tmp_path / "out" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000, name
    # 001 §4.4: about 8 µm at most for a reading uncertainty of about 2.5 µm (k = 2).
    U = float(re.search(r"max U\(k=2\) = ([\d.]+) µm", proc.stdout).group(1))
    assert 2.0 < U < 20.0, proc.stdout
    # The comparisons of 001 §3.2 are printed: the plate's thermal scale and the laser profiles.
    assert "3.60 µm per 100 mm" in proc.stdout
    diffs = [float(v) for v in re.findall(r"laser interferometer \(offsets removed\): max ([\d.]+) µm", proc.stdout)]
    assert len(diffs) == 2 and max(diffs) < U
