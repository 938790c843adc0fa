"""The engine's under-resolution check of a map model (issue 22: built once, olti_drake.estimation.resolution; issue
24 class 8: a u too small without a warning), run by the volumetric machine (tests/estimation/
test_volumetric_resolution.py) and the N-joint robot alike.

The statistic on nested fits drawn by hand (the difference of two fits of one truth has the variance u_f² − u²; a
bias beyond it is what the coarse representation misses), then an N-joint robot: random UR5 poses within the joint
limits, 4 stations, 10 um noise, a harmonic truth with backlash (not in the model family) whose location errors the
distances cannot see are zero (tests/estimation/test_serial_prediction_u.py), so unseen tool points compare without
a fitted alignment. On a 20 deg grid the maps miss the truth between their nodes: the check names the 10 deg grid,
inflates every u, and the unseen tool points beyond 3 u fall; on a 10 deg grid it stays quiet.
"""

import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import Fit
from olti_drake.estimation.resolution import RESOLUTION_RATIO, Finer, inflate, resolution_check
from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial
from olti_drake.estimation.serial_uncertainty import tool_point_uncertainty
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import SerialCampaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.propagation import with_lack_of_fit
from olti_drake.model.serial import synthetic_campaign
from tests.estimation.test_serial_prediction_u import NOISE_MM, RANGES, TOOL, _gauged_truth


# -- the statistic ------------------------------------------------------------------------------------------------
def _nested(rng, n=4000, bias=0.0):
    """(p, u, p_f, u_f): a coarse fit p (u 1 um) and a finer one p_f (u_f 1.3 um) of one truth, their difference
    drawn with the nested fits' variance u_f² − u², plus a ``bias`` (mm) the coarse one misses."""
    u, u_f = np.full((n, 3), 1e-3), np.full((n, 3), 1.3e-3)
    p_f = rng.normal(size=(n, 3))
    p = p_f + rng.normal(size=(n, 3)) * np.sqrt(u_f ** 2 - u ** 2) + bias * np.sin(np.arange(n))[:, None]
    return p, u, p_f, u_f


def _finer(p_f, u_f, **kw):
    return Finer(this="coarse", finer="fine", rerun="--fine", points=lambda: (p_f, u_f), **kw)


def test_nested_fits_of_one_truth_are_resolved_and_a_missed_bias_inflates_u():
    rng = np.random.default_rng(0)
    p, u, p_f, u_f = _nested(rng)
    quiet = resolution_check(p, u, _finer(p_f, u_f))
    assert quiet["done"] and quiet["resolved"] and quiet["inflation"] == 1.0 and "warning" not in quiet
    assert quiet["ratio"] < 0.2 < quiet["difference_over_u_rms"]  # (the fits' own spread is no misfit)
    p, u, p_f, u_f = _nested(rng, bias=2e-3)  # RMS 2 u / sqrt(2): a misfit of 1.41 u
    loud = resolution_check(p, u, _finer(p_f, u_f, extra={"grid_step_deg": 20.0}))
    assert not loud["resolved"] and loud["ratio"] == pytest.approx(np.sqrt(2), rel=0.05)
    assert loud["inflation"] == pytest.approx(np.sqrt(3), rel=0.05) and loud["grid_step_deg"] == 20.0
    assert "--fine" in loud["warning"] and loud["threshold"] == RESOLUTION_RATIO
    # the rows' order does not matter
    order = rng.permutation(len(p))
    again = resolution_check(p[order], u[order], _finer(p_f[order], u_f[order]))
    assert again["ratio"] == pytest.approx(loud["ratio"], rel=1e-12)


def test_no_comparison_is_said_and_nothing_is_inflated():
    p, u = np.zeros((5, 3)), np.zeros((5, 3))
    assert resolution_check(p, u, _finer(p, u)) is None  # (every point fixed by the gauge)

    def refused():
        raise InputError("c.csv: not identifiable: J1_forward_deg[3]")
    out = resolution_check(p, u + 1e-3, Finer(this="coarse", finer="fine", points=refused))
    assert out == {"method": out["method"], "done": False, "why": "c.csv: not identifiable: J1_forward_deg[3]"}
    out = resolution_check(p, u + 1e-3, Finer(this="coarse", why="no finer grid"))
    assert not out["done"] and out["why"] == "no finer grid"
    fit = Fit(["a"], np.zeros(1), np.ones(1), np.eye(1), np.zeros(3), 1, 1.0, "lm")
    inflate(fit, out)
    assert fit.resolution is out and fit.std[0] == 1.0 and not fit.warnings


@pytest.mark.parametrize("deferred", [False, True])
def test_inflation_scales_the_covariance_and_keeps_only_the_lack_of_fit_it_does_not_hold(deferred):
    check = {"done": True, "inflation": 2.0, "u_rms_mm": 1e-3, "warning": "under-resolution check: ..."}
    fit = Fit(["a", "b"], np.zeros(2), np.array([1e-3, 2e-3]),
              (lambda: np.diag([1e-6, 4e-6])) if deferred else np.diag([1e-6, 4e-6]), np.zeros(3), 1, 1.0, "lm")
    fit.lack_of_fit_mm = 2e-3  # (g² − 1) u_rms² = 3e-6 mm² of its 4e-6 held by the inflation: 1 um left
    fit.notes = ["lack of fit: ..."]
    inflate(fit, check)
    assert np.allclose(fit.covariance, np.diag([4e-6, 16e-6]), rtol=1e-12) and np.allclose(fit.std, [2e-3, 4e-3])
    assert fit.lack_of_fit_mm == pytest.approx(1e-3, rel=1e-9) and fit.warnings == [check["warning"]]
    assert len(fit.notes) == 1 and "1 um of it is added" in fit.notes[0]
    small = Fit(["a"], np.zeros(1), np.ones(1), np.eye(1), np.zeros(3), 1, 1.0, "lm")
    small.lack_of_fit_mm = 1e-3
    inflate(small, check)
    assert small.lack_of_fit_mm == 0.0


# -- an N-joint robot ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ur5():
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = _gauged_truth(chain, seed=3)
    c = synthetic_campaign(truth, 400, seed=4, ranges_deg=RANGES, noise_mm=NOISE_MM)
    camp = SerialCampaign("distance", c.distance_commands, c.distance_dirs, np.arange(len(c.station)) + 2, "c.csv",
                          station=c.station, displacement_mm=c.displacement_mm)
    unseen = synthetic_campaign(truth, 400, seed=104, ranges_deg=RANGES)
    return chain, camp, unseen, truth.positions(unseen.commands, unseen.dirs)


def _identify(ur5, **kw):
    chain, camp, _, _ = ur5
    return identify_serial(chain, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, **kw))


def _beyond_3u(ident, ur5) -> float:
    """The share of unseen tool-point coordinates farther from the truth than 3 u (u with the lack of fit)."""
    _, _, unseen, truth = ur5
    model, fit = ident.model, ident.fit
    idx = [fit.names.index(n) for n in model.names]
    p, u = tool_point_uncertainty(model.with_vector(fit.x[idx]), unseen.commands, unseen.dirs,
                                  cov=fit.covariance[np.ix_(idx, idx)])
    return float(np.mean(np.abs(p - truth) > 3 * with_lack_of_fit(u, fit.lack_of_fit_mm)))


def test_a_too_coarse_grid_is_named_and_its_u_inflated_to_cover_unseen_points(ur5):
    checked = _identify(ur5, grid_step_deg=20.0)
    plain = _identify(ur5, grid_step_deg=20.0, check_resolution=False)
    res = checked.fit.resolution
    assert res["done"] and not res["resolved"] and res["finer_grid_step_deg"] == 10.0 and res["inflation"] > 1.1
    assert any("--grid-step-deg 10" in w and "inflated" in w for w in checked.fit.warnings)
    assert plain.fit.resolution is None
    assert np.array_equal(checked.fit.x, plain.fit.x)  # the same solution, only its u inflated
    assert np.allclose(checked.fit.std, plain.fit.std * res["inflation"], rtol=1e-9)
    before, after = _beyond_3u(plain, ur5), _beyond_3u(checked, ur5)
    assert before > 0.03 and after < 0.5 * before, (before, after)


def test_an_adequate_grid_keeps_the_check_quiet_and_u_unchanged(ur5):
    checked = _identify(ur5, grid_step_deg=10.0)
    res = checked.fit.resolution
    assert res["done"] and res["resolved"] and res["inflation"] == 1.0 and res["ratio"] < RESOLUTION_RATIO
    plain = _identify(ur5, grid_step_deg=10.0, check_resolution=False)
    assert np.array_equal(checked.fit.std, plain.fit.std)
    assert checked.fit.lack_of_fit_mm == plain.fit.lack_of_fit_mm
    assert _beyond_3u(checked, ur5) <= 0.01


def test_the_default_grid_with_the_prior_and_a_geometric_model_are_not_checked(ur5):
    """The smoothness prior on the default grid sets what the maps hold (not the grid): no refit; a geometric
    model has no representation to refine."""
    assert _identify(ur5).fit.resolution is None
    assert _identify(ur5, model="dh").fit.resolution is None


def test_given_grids_are_refined_by_a_node_between_each_two():
    from olti_drake.estimation.serial_identification import _halved

    assert _halved([-90, -30, 0, 90]) == [-90, -60, -30, -15, 0, 45, 90]


def test_the_cli_states_the_check_and_olti_uncertainty_says_what_it_holds(ur5, tmp_path, capsys):
    """olti identify --grid-step-deg 20: the result's resolution_check and inflated u, the summary's line and
    warning; olti uncertainty of that result says its propagation holds the readings' errors alone."""
    import json

    from olti_drake.cli import main
    from olti_drake.io.serial_io import write_serial_campaign

    _, camp, _, _ = ur5
    write_serial_campaign(tmp_path / "c.csv", camp.commands, camp.dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    common = ["--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm", ",".join(f"{v:g}" for v in TOOL),
              "--model", "errormap", "--grid-step-deg", "20"]
    assert main(["identify", str(tmp_path / "c.csv"), *common, "--out", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "resolution check: the fit on a 10 deg grid moves the tool points" in out and "u inflated" in out
    assert "warning: under-resolution check" in out and "--grid-step-deg 10" in out
    doc = json.loads((tmp_path / "r.json").read_text())
    check = doc["resolution_check"]
    assert check["grid_step_deg"] == 20.0 and check["finer_grid_step_deg"] == 10.0 and check["inflation"] > 1.1
    assert any("under-resolution check" in w for w in doc["warnings"])
    assert main(["uncertainty", str(tmp_path / "r.json"), str(tmp_path / "c.csv"), "--method", "linear",
                 "--workspace-poses", "20", "--out", str(tmp_path / "u.json")]) == 0
    notes = json.loads((tmp_path / "u.json").read_text())["notes"]
    assert any("under-resolution check's inflation" in n and "readings' errors alone" in n for n in notes), notes
