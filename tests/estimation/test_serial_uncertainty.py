"""olti uncertainty for robots from a model file (issue 13, item 7): every parameter, the predicted tool point over
the workspace (3D map as slices)."""

import json
import os

import numpy as np
import pytest

from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import write_serial_campaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import synthetic_campaign, synthetic_truth
from olti_calls import error_line, olti_sub

TOOL = (40.0, -25.0, 60.0)
RANGES = np.array([[-90.0, 90.0]] * 6)


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    d = tmp_path_factory.mktemp("unc")
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 150, seed=4, ranges_deg=RANGES, noise_mm=0.001)
    write_serial_campaign(d / "campaign.csv", camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    run = olti_sub("identify", d / "campaign.csv", "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm",
                   "40,-25,60", "--model", "errormap", "--grid-step-deg", "45", "--out", d / "result.json")
    assert run.returncode == 0, run.stderr
    return d


def test_linear_uncertainty_of_every_parameter_and_the_workspace(identified, tmp_path):
    """The uncertainty file has the result's keys (error maps per joint, stations, dead paths) with u > 0; the
    predicted tool point's U over the workspace is stated and drawn; the tool-point u equals sqrt(diag(J C J^T))
    from the written per-parameter covariance (computed here densely)."""
    d = identified
    run = olti_sub("uncertainty", d / "result.json", d / "campaign.csv", "--method", "linear", "--map",
                   tmp_path / "m.png", "--workspace-poses", "50", "--out", tmp_path / "u.json")
    assert run.returncode == 0, run.stderr
    unc = json.loads((tmp_path / "u.json").read_text())
    res = json.loads((d / "result.json").read_text())
    for joint, m in res["error_map"].items():
        assert np.shape(unc["error_map"][joint]["forward_deg"]) == np.shape(m["forward_deg"])
        assert min(unc["error_map"][joint]["forward_deg"]) > 0
    assert np.shape(unc["stations_mm"]) == np.shape(res["stations_mm"]) and min(unc["dead_paths_mm"]) > 0
    ws = unc["workspace"]
    assert 0 < ws["expanded_um_mean"] <= ws["expanded_um_max"]
    assert (tmp_path / "m.png").stat().st_size > 20_000
    assert "U (k = 2) max" in run.stdout


def test_tool_point_u_is_the_propagated_covariance():
    from olti_drake.estimation.serial_uncertainty import tool_point_uncertainty
    from olti_drake.model.serial import build_position_model

    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 30, seed=9, ranges_deg=RANGES)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=45, tool_offset_mm=TOOL)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(model.n_params, model.n_params)) * 1e-3
    cov = A @ A.T
    p, u = tool_point_uncertainty(model, camp.commands, camp.dirs, cov=cov)
    J = model.jacobian(camp.commands, camp.dirs)[1].tocsr().toarray()
    assert np.allclose(u.ravel(), np.sqrt(np.diag(J @ cov @ J.T)), rtol=1e-10)
    samples = rng.multivariate_normal(model.start_vector(), cov * 1e-4, size=400)
    _, u_mc = tool_point_uncertainty(model, camp.commands, camp.dirs, samples=samples)
    assert np.allclose(u_mc, u * 1e-2, rtol=0.2)  # the sample spread of a linear-enough model, 400 samples


def test_the_wrong_campaign_is_refused(identified, tmp_path):
    d = identified
    lines = (d / "campaign.csv").read_text().splitlines()
    (tmp_path / "other.csv").write_text("\n".join(lines[:-3]) + "\n")
    run = olti_sub("uncertainty", d / "result.json", tmp_path / "other.csv", "--method", "linear", "--out",
                   tmp_path / "u.json")
    error_line(run.returncode, run.stderr, "not the campaign")
    assert not (tmp_path / "u.json").exists()


def test_without_tool_offset_the_model_is_rebuilt_around_the_fitted_tool_point(identified, tmp_path):
    """No --tool-offset-mm: the start's tool point lies on the last axis, which hides the last joint's map; the
    fitted tool point is off the axis, so the model is rebuilt around it: the same result as with the offset
    given (residual and tool offset), and a note says so."""
    d = identified
    run = olti_sub("identify", d / "campaign.csv", "--robot", "ur5", "--tool-frame", "tool0", "--model", "errormap",
                   "--grid-step-deg", "45", "--out", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    a = json.loads((tmp_path / "r.json").read_text())
    b = json.loads((d / "result.json").read_text())
    assert "wrist_3_joint" in a["error_map"] and any("rebuilt around it" in n for n in a["notes"])
    assert a["residual_rms_mm"] == pytest.approx(b["residual_rms_mm"], rel=1e-6)
    assert np.allclose(a["tool_offset_mm"], b["tool_offset_mm"], atol=1e-6)


def test_monte_carlo_agrees_with_the_linear_propagation(identified, tmp_path):
    """JCGM 101 Monte Carlo (300 trials, the problem re-solved per trial) against JCGM 100 linear propagation
    of the same budget: every parameter's u within the sampling error of 300 trials (±25 % at the extremes,
    median ratio within 5 %), the workspace U within 10 %. Seeded: the same seed gives the same file."""
    d = identified
    outs = {}
    for method, extra in (("linear", []), ("mc", ["--trials", "300", "--seed", "3"])):
        outs[method] = tmp_path / f"{method}.json"
        run = olti_sub("uncertainty", d / "result.json", d / "campaign.csv", "--method", method, *extra,
                       "--workspace-poses", "60", "--out", outs[method])
        assert run.returncode == 0, run.stderr
    lin, mc = (json.loads(outs[m].read_text()) for m in ("linear", "mc"))
    a, b = np.array(mc["parameters"]["std"]), np.array(lin["parameters"]["std"])
    ratio = a[b > 0] / b[b > 0]
    assert 0.95 < np.median(ratio) < 1.05 and 0.75 < ratio.min() and ratio.max() < 1.25, (np.median(ratio), ratio.min(),
                                                                                          ratio.max())
    assert mc["workspace"]["expanded_um_mean"] == pytest.approx(lin["workspace"]["expanded_um_mean"], rel=0.1)
    again = tmp_path / "again.json"
    assert olti_sub("uncertainty", d / "result.json", d / "campaign.csv", "--method", "mc", "--trials", "300", "--seed",
                    "3", "--workspace-poses", "60", "--out", again).returncode == 0
    assert json.loads(again.read_text())["parameters"] == mc["parameters"]
