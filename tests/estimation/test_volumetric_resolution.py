"""The volumetric model's under-resolution check (issue 24, class 8: "uncertainty that is too small without a
warning"): on the shipped machine_3d walk-through the default knots (one cubic per axis on a 6 x 5 x 4 grid)
cannot hold the truth and the stated u was ~3x too small. The identification now refits the campaign on finer
knots (``estimation.volumetric.finer_knot_spacing``) and compares the tool points of the two at every target
against their stated u; when they differ beyond it, the result says so (``resolution_check``, a warning naming
the ``--knot-spacing-mm`` to use) and every stated u is inflated by the measured factor.

The campaigns are the numpy twin of the shipped diagram (``model.machine.simulate_machine_campaign_3d``: pan/tilt
heads aimed open loop, 001 Table 4 noise), truth = sums of sines in no spline family, seeded.
"""

import json

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.estimation.multilateration import load_machine_campaign
from olti_drake.estimation.volumetric import (VolumetricOptions, finer_knot_spacing, identify_volumetric,
                                              volumetric_campaign)
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.propagation import predicted_std
from olti_drake.model.volumetric3d import MachineConfig

SHIPPED_TOOLS = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0), (0.0, 80.0, 140.0))


def _campaign(path, grid, truth_knots_mm):
    """(campaign, truth dict) of the simulated pan/tilt campaign on a command ``grid`` with three tools; the
    truth's sines have periods >= 4 intervals of ``truth_knots_mm``."""
    from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d

    cfg = MachineConfig(tool_offsets_mm=SHIPPED_TOOLS, knot_spacing_mm=truth_knots_mm)
    cols, truth = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=grid, tools=(0, 1, 2), seed=0))
    write_machine_campaign(cols, path)
    data = volumetric_campaign(load_machine_campaign(path))
    assert np.allclose(truth["commands_mm"], data.commands_mm) and np.array_equal(truth["tools"], data.tool)
    return data, np.asarray(truth["targets_mm"], float)


def _normalized(result, data, truth_mm):
    """|identified − true| / u of every tool-point coordinate of the campaign's targets (u > 0: tool 0 at the
    travel start is the origin, exact by the gauge)."""
    p, J = result.model.jacobian(data.commands_mm, data.tool, result.params)
    u = predicted_std(J, result.covariance)
    seen = u > 1e-9
    return np.abs(p - truth_mm)[seen] / u[seen]


def _identify(data, **kw):
    return identify_volumetric(data, VolumetricOptions(tool_offsets_mm=SHIPPED_TOOLS, **kw))


@pytest.fixture(scope="module")
def coarse(tmp_path_factory):
    """The shipped walk-through's campaign (6 x 5 x 4 grid, truth on 50 mm knots): the default knots, 400 mm."""
    path = tmp_path_factory.mktemp("coarse") / "campaign.csv"
    data, truth = _campaign(path, (6, 5, 4), 50.0)
    return path, data, truth


def test_the_finer_knots_are_the_finest_the_positions_identify():
    cfg = MachineConfig(travel_mm={"X": (0, 400), "Y": (0, 300), "Z": (0, 250)}, knot_spacing_mm=400.0)
    grid = np.stack(np.meshgrid(np.linspace(0, 400, 6), np.linspace(0, 300, 5), np.linspace(0, 250, 4),
                                indexing="ij"), -1).reshape(-1, 3)
    # s/2 = 200 mm would give Z 5 coefficients on 4 positions; 250 mm: X 2, Y 2, Z 1 intervals.
    assert finer_knot_spacing(cfg, grid) == 250.0
    import dataclasses
    assert finer_knot_spacing(dataclasses.replace(cfg, knot_spacing_mm=250.0), grid) is None


def test_too_coarse_knots_are_named_and_their_u_inflated_to_cover_the_truth(coarse):
    path, data, truth = coarse
    plain = _identify(data, check_resolution=False)
    before = _normalized(plain, data, truth)
    assert plain.model.config.knot_spacing_mm == 400.0
    assert np.mean(before <= 3) < 0.9, "the campaign is meant to be too coarse for one cubic per axis"
    checked = _identify(data)
    res = checked.resolution
    assert res["done"] and not res["resolved"] and res["finer_knot_spacing_mm"] == 250.0
    assert res["ratio"] > res["threshold"] and res["inflation"] > 2
    assert any("--knot-spacing-mm 250" in w and "inflated" in w for w in checked.fit.warnings)
    # The same solution, its covariance inflated by the measured factor.
    assert np.array_equal(checked.params, plain.params)
    assert np.allclose(checked.covariance, plain.covariance * res["inflation"] ** 2, rtol=1e-9, atol=0)
    after = _normalized(checked, data, truth)
    assert np.mean(after <= 3) >= 0.95, (np.mean(before <= 3), np.mean(after <= 3))
    assert np.allclose(after, before / res["inflation"])


def test_the_cli_states_the_check_in_the_result_and_the_summary(coarse, tmp_path, capsys):
    path, _, _ = coarse
    tools = ";".join(",".join(f"{v:g}" for v in t) for t in SHIPPED_TOOLS)
    code = main(["identify", str(path), "--model", "volumetric", "--tool-offsets-mm", tools,
                 "--out", str(tmp_path / "r.json")])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads((tmp_path / "r.json").read_text())
    res = doc["resolution_check"]
    assert res["done"] and not res["resolved"] and res["inflation"] > 2
    assert "inflated" in doc["uncertainty"]["method"]
    assert any("under-resolution check" in w for w in doc["warnings"])
    assert "resolution check:" in out and "too coarse: u inflated" in out and "--knot-spacing-mm 250" in out
    # With the knots it names, the check cannot refine further on this grid: it says so, u is not touched.
    code = main(["identify", str(path), "--model", "volumetric", "--tool-offsets-mm", tools, "--knot-spacing-mm",
                 "250", "--out", str(tmp_path / "r250.json")])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads((tmp_path / "r250.json").read_text())
    assert doc["resolution_check"]["done"] is False and "resolution check not possible" in out
    assert "inflated" not in doc["uncertainty"]["method"]


def test_adequate_knots_keep_the_check_quiet_and_u_unchanged(tmp_path):
    """9 x 8 x 7 positions, truth on 100 mm knots: the default 125 mm knots hold it (every coordinate within 3 u);
    the fit on the finer knots agrees within the stated u, nothing is inflated or warned."""
    data, truth = _campaign(tmp_path / "campaign.csv", (9, 8, 7), 100.0)
    checked = _identify(data)
    res = checked.resolution
    assert res["done"] and res["resolved"] and res["inflation"] == 1.0 and "warning" not in res
    assert res["ratio"] < res["threshold"]
    assert not checked.fit.warnings
    plain = _identify(data, check_resolution=False)
    assert np.array_equal(checked.covariance, plain.covariance)
    assert np.mean(_normalized(checked, data, truth) <= 3) >= 0.95
