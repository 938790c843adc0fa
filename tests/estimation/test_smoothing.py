"""Issue 23 items 1-2: maps that span the data, and the roughness prior whose weight the data choose.

Campaigns the tool did not plan: random UR5 poses within the joint limits, approached in the order of the poses
(formats.md's direction rule: near a range end most approaches come from inside, so the end nodes of one
direction are barely reached), 4 stations, 2 um reading noise; truths not in the model family (harmonic joint
deviations with backlash, continuous). Unseen readings: other random poses of the same kind.
"""

import numpy as np
import pytest

from olti_drake.estimation.calibration import InputError
from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial
from olti_drake.io.serial_io import SerialCampaign, load_robot
from olti_drake.model.errormap import ErrorMap
from olti_drake.model.propagation import predicted_std
from olti_drake.model.serial import DistanceMeasurement, synthetic_campaign, synthetic_truth
from olti_calls import olti_sub

NOISE_MM = 0.002
TOOL = (40.0, -25.0, 60.0)


# -- the model layer: the roughness operator ----------------------------------------------------------------------
def test_roughness_is_zero_on_lines_and_the_second_derivative_on_parabolas():
    grid = np.array([-30.0, -10.0, 0.0, 15.0, 45.0])  # uneven spacing
    emap = ErrorMap(grid, np.zeros(5), np.zeros(5))
    R = emap.roughness()
    assert R.shape == (9, 10)  # forward, reverse, backlash rows at the 3 interior nodes
    line = np.concatenate([0.01 + 0.002 * grid, -0.03 + 0.001 * grid])
    assert np.max(np.abs(R @ line)) < 1e-15
    a = 1e-4  # f = a θ²: f'' = 2a at every node; the row holds √((h0 + h1)/2) times it
    f = a * grid ** 2
    share = np.sqrt(0.5 * (np.diff(grid)[:-1] + np.diff(grid)[1:]))
    got = (R @ np.concatenate([f, np.zeros(5)]))[:3]
    assert got == pytest.approx(2 * a * share, rel=1e-12)
    # the backlash rows see f − r: a parabolic backlash, straight branches otherwise
    assert (R @ np.concatenate([f, np.zeros(5)]))[6:] == pytest.approx(2 * a * share, rel=1e-12)
    assert ErrorMap(grid[:2], np.zeros(2), np.zeros(2)).roughness().shape == (0, 4)
    assert emap.roughness(bidirectional=False).shape == (3, 10)


def test_each_group_shows_its_own_roughness_and_none_is_taken_smoother_than_the_common_weight():
    """smoothing.group_weights on a linear toy: three maps of 20 nodes (second-difference rows), 50 readings, each
    of two maps at random points (linear interpolation). A smooth map A and a rough map B: the common weight is
    their average roughness per parameter, so B's own weight is the common one times B's share of the parameters
    (its roughness is its own, not A's); A keeps the common weight (the readings may show a map rougher, never
    smoother); C, which no reading sees, keeps it too. The order of the groups changes nothing."""
    from olti_drake.estimation.smoothing import group_weights, reml_scan

    k = np.arange(20.0)
    D2 = np.diff(np.eye(20), 2, axis=0)  # (18, 20)
    R = {name: np.hstack([D2 if j == i else np.zeros((18, 20)) for j in range(3)]) for i, name in enumerate("ABC")}
    truth = np.concatenate([1e-3 * np.sin(2 * np.pi * k / 40), 1e-3 * np.sin(2 * np.pi * k / 7), np.zeros(20)])
    rng = np.random.default_rng(4)

    def at_random_points(m):
        t = rng.uniform(0, 19, m)
        i = np.minimum(t.astype(int), 18)
        W = np.zeros((m, 20))
        W[np.arange(m), i], W[np.arange(m), i + 1] = 1 - (t - i), t - i
        return W * rng.normal(size=(m, 1))

    J = np.hstack([at_random_points(50), at_random_points(50), np.zeros((50, 20))])
    sigma = 1e-5
    y = J @ truth + rng.normal(0, sigma, 50)
    A_eq = np.zeros((2, 60))
    A_eq[0, 40:], A_eq[1, 40:] = 1.0, k  # (C's constant and trend: no reading, no roughness -- held)
    args = (np.zeros(60), A_eq, float(y @ y), 50)
    H, g = J.T @ J, -J.T @ y
    common = reml_scan(H, None, sum(Rg.T @ Rg for Rg in R.values()), g, *args, floor=sigma ** 2).weight
    got = group_weights(H, None, R, g, *args, common, floor=sigma ** 2)
    e = got.effective
    assert got.weights["B"] == pytest.approx(common * e["B"] / (e["A"] + e["B"]), rel=0.15), (got, common)
    assert got.weights["A"] == common and got.weights["C"] == common
    assert e["C"] < 0.5 and min(e["A"], e["B"]) > 10.0
    again = group_weights(H, None, {name: R[name] for name in "CBA"}, g, *args, common, floor=sigma ** 2)
    assert again.weights == pytest.approx(got.weights, rel=1e-9)


# -- identification on campaigns the tool did not plan ------------------------------------------------------------
@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5", "tool0")


def _campaign(truth, n, seed, directions="sequence"):
    c = synthetic_campaign(truth, n, seed, directions=directions, noise_mm=NOISE_MM)
    return SerialCampaign("distance", c.distance_commands, c.distance_dirs, np.arange(len(c.station)) + 2, "c.csv",
                          station=c.station, displacement_mm=c.displacement_mm)


def _unseen(ident, truth, n=300, seed=999, directions="sequence"):
    """(errors, u) of the readings of unseen poses from every identified station, mm (u from the covariance)."""
    un = synthetic_campaign(truth, n, seed, directions=directions)
    meas, fit = ident.measurement, ident.fit
    model = meas.model
    for m in model.maps:
        object.__setattr__(m.emap, "outside", "clamp")
    nt = len(truth.stations_mm)
    st = np.repeat(np.arange(nt), n)
    cmd, dirs = np.tile(un.commands, (nt, 1)), None if un.dirs is None else np.tile(un.dirs, (nt, 1))
    lay = meas.layout(fit.x)
    probe = DistanceMeasurement(model, cmd, dirs, st, np.zeros(len(st)), np.array(lay["stations_mm"]),
                                np.array(lay["dead_paths_mm"]))
    r, J = probe.residuals(fit.x)  # = predicted reading (the reading given is 0)
    p = truth.positions(cmd, dirs)
    true = np.linalg.norm(p - truth.stations_mm[st], axis=1) - truth.dead_paths_mm[st]
    return r - true, np.hypot(predicted_std(J, fit.covariance), fit.lack_of_fit_mm)


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.fixture(scope="module")
def random_campaign(ur5):
    truth = synthetic_truth(ur5, 4)
    return truth, _campaign(truth, 240, 4)


@pytest.fixture(scope="module")
def smoothed(ur5, random_campaign):
    """The default options (errormap, smoothing auto: a 7.5 deg grid) on the random-pose campaign."""
    truth, camp = random_campaign
    return identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL))


def test_a_random_pose_campaign_identifies_with_the_default_options(smoothed, random_campaign):
    truth, camp = random_campaign
    ident = smoothed
    s = ident.fit.smoothing
    assert s["method"] == "restricted maximum likelihood" and s["weight"] > 0 and np.isfinite(s["score"])
    assert 0 < s["effective_parameters"] < len(ident.fit.names)
    notes = " ".join(ident.fit.notes)
    assert "smoothness prior on the maps" in notes and f"{s['weight']:.4g}" in notes
    # the end nodes one direction does not reach are no parameters, and are named
    assert "no parameters" in notes and "follows" in notes
    e, u = _unseen(ident, truth)
    assert _rms(e) < 0.05  # mm; the geometric model is ~0.14 mm on such a truth


def test_smoothing_beats_the_ridge_reference_on_unseen_poses(ur5, smoothed, random_campaign):
    """The same family with a weak ridge (--regularize, smoothing off) as the reference."""
    truth, camp = random_campaign
    ref = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, smoothing="off",
                                                                 regularize=True, grid_step_deg=7.5))
    e_s, _ = _unseen(smoothed, truth)
    e_r, _ = _unseen(ref, truth)
    assert _rms(e_s) <= 0.95 * _rms(e_r), (_rms(e_s), _rms(e_r))
    assert ref.fit.smoothing is None


def test_the_stated_uncertainty_covers_the_unseen_errors(smoothed, random_campaign):
    truth, _ = random_campaign
    e, u = _unseen(smoothed, truth)
    ratio = _rms(e) / _rms(u)
    assert 0.5 <= ratio <= 2.0, ratio
    assert np.mean(np.abs(e) > 3 * u) <= 0.05


def test_tied_nodes_keep_the_backlash_of_the_nearest_node_read_both_ways(smoothed):
    model, x = smoothed.model, smoothed.fit.x
    A, tied, targets = model.ties(smoothed.measurement.commands, smoothed.measurement.dirs)
    assert len(tied) > 0
    assert np.max(np.abs(A @ x[:model.n_params])) < 1e-9
    assert any("backlash" in t for t in targets)


def test_a_given_weight_reproduces_the_automatic_choice(ur5, smoothed, random_campaign):
    _, camp = random_campaign
    w = smoothed.fit.smoothing["weight"]
    again = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, smoothing=w))
    assert again.fit.smoothing["method"] == "given" and again.fit.smoothing["weight"] == w
    assert np.max(np.abs(again.fit.x - smoothed.fit.x)) < 1e-6
    # and the weight is what it says: 100 x the weight gives another (smoother) solution
    strong = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, smoothing=100 * w))
    R = smoothed.measurement.roughness()
    assert np.linalg.norm(R @ strong.fit.x) < 0.8 * np.linalg.norm(R @ smoothed.fit.x)
    assert strong.residual_rms_mm > 1.5 * smoothed.residual_rms_mm


def test_a_bad_smoothing_value_is_one_line(ur5, random_campaign):
    _, camp = random_campaign
    with pytest.raises(InputError, match="smoothing: 'auto', 'off' or a weight >= 0"):
        identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, smoothing=-1.0))


def test_the_program_before_the_solve_carries_the_prior_for_every_solver(tmp_path, ur5):
    """od.calibration_problem's prog holds the smoothness prior at the weight the data chose: SNOPT on it and the
    default LM reach the same solution, and the identification of SNOPT's result states the same prior."""
    import olti_drake as od
    from pydrake.solvers import SnoptSolver

    from olti_drake.io.serial_io import write_serial_campaign

    truth = synthetic_truth(ur5, 6)
    c = synthetic_campaign(truth, 120, 6, directions="sequence", noise_mm=NOISE_MM)
    write_serial_campaign(tmp_path / "c.csv", c.distance_commands, c.distance_dirs, station=c.station,
                          displacement_mm=c.displacement_mm)
    options = dict(model="errormap", robot="ur5", tool_frame="tool0", tool_offset_mm=TOOL, grid_step_deg=30.0)
    lm = od.calibration_problem(tmp_path / "c.csv", **options).fit()
    problem = od.calibration_problem(tmp_path / "c.csv", **options)
    assert any("smoothness prior" in b.evaluator().get_description() for b in problem.prog.GetAllCosts())
    result = SnoptSolver().Solve(problem.prog)
    assert result.is_success()
    mine = problem.identification(result)
    assert mine.fit.smoothing["weight"] == pytest.approx(lm.fit.smoothing["weight"], rel=1e-9)
    cost = lambda f: 0.5 * float(np.sum(f.residuals ** 2))  # noqa: E731
    assert cost(mine.fit) == pytest.approx(cost(lm.fit), rel=1e-6)
    assert np.max(np.abs(mine.fit.x - lm.fit.x)) < 1e-4


def _unseen_points(ident, truth, n=300, seed=998, directions="sequence"):
    """(errors (3n,), u (3n,)) of unseen tracker points (the identified frame), mm."""
    from olti_drake.model.serial import PointMeasurement

    un = synthetic_campaign(truth, n, seed, directions=directions)
    model, fit = ident.measurement.model, ident.fit
    for m in model.maps:
        object.__setattr__(m.emap, "outside", "clamp")
    probe = PointMeasurement(model, un.commands, un.dirs, np.zeros((n, 3)))
    r, J = probe.residuals(fit.x)  # = the predicted point (the point given is 0)
    return r - un.points_mm.ravel(), np.hypot(predicted_std(J, fit.covariance), fit.lack_of_fit_mm)


@pytest.fixture(scope="module")
def seven():
    from pathlib import Path

    return load_robot(str(Path(__file__).resolve().parents[1] / "data" / "seven_joint.urdf"), "tool0")


def test_a_seven_joint_tracker_campaign_with_the_default_options(seven):
    truth = synthetic_truth(seven, 2)
    c = synthetic_campaign(truth, 250, 2, directions="sequence", noise_mm=NOISE_MM)
    camp = SerialCampaign("point", c.commands, c.dirs, np.arange(250) + 2, "t.csv", points_mm=c.points_mm)
    ident = identify_serial(seven, camp, SerialIdentificationOptions(tool_offset_mm=TOOL))
    geo = identify_serial(seven, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, model="dh"))
    e, u = _unseen_points(ident, truth)
    e_geo, _ = _unseen_points(geo, truth)
    assert ident.fit.smoothing["method"] == "restricted maximum likelihood"
    assert _rms(e) < 0.5 * _rms(e_geo), (_rms(e), _rms(e_geo))
    assert 0.5 <= _rms(e) / _rms(u) <= 2.0, _rms(e) / _rms(u)


@pytest.mark.parametrize("seed", [7, 8])
def test_a_small_tracker_set_is_not_overfitted(ur5, seed):
    """80 tracker points against ~1 000 map values: the default fit predicts unseen points no worse than the
    geometric model (the prior holds the maps near straight where the points cannot shape them), does not run
    through every point (seed 8: the likelihood without the readings' stated variance is flat down to the
    interpolating weight, whose fit had no residual and a u of 0.3 um against errors of 40 um), and its u -- the
    fit's covariance and its lack of fit -- covers the unseen errors."""
    truth = synthetic_truth(ur5, seed)
    c = synthetic_campaign(truth, 80, seed, directions="sequence", noise_mm=NOISE_MM)
    camp = SerialCampaign("point", c.commands, c.dirs, np.arange(80) + 2, "t.csv", points_mm=c.points_mm)
    ident = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL))
    geo = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, model="dh"))
    e, u = _unseen_points(ident, truth)
    e_geo, _ = _unseen_points(geo, truth)
    assert _rms(e) <= _rms(e_geo), (_rms(e), _rms(e_geo))
    s = ident.fit.smoothing
    assert s["effective_parameters"] < 0.9 * 3 * 80, s
    assert _rms(ident.fit.residuals) > NOISE_MM  # (not through the points)
    assert 0.5 <= _rms(e) / _rms(u) <= 2.0, _rms(e) / _rms(u)
    assert np.mean(np.abs(e) <= 3 * u) >= 0.95


def test_the_lack_of_fit_of_a_geometric_model_joins_the_u_of_its_predictions(ur5):
    """A geometric (dh) model of a robot with joint deviations: the residuals (~0.16 mm) are the model's error, not
    the readings' 2 um (the budget's). Its parameters' covariance alone states unseen points ~3-5 x too small; the
    lack of fit (the residuals' sigma beyond the budget's reading u) added to each predicted coordinate covers
    them, and the fit says so."""
    from olti_drake.model.budget import Budget, Contributor

    truth = synthetic_truth(ur5, 8)
    c = synthetic_campaign(truth, 250, 8, directions="sequence", noise_mm=NOISE_MM)
    camp = SerialCampaign("point", c.commands, c.dirs, np.arange(250) + 2, "t.csv", points_mm=c.points_mm)
    budget = Budget("tracker", contributors=[Contributor("u1", "tracker noise", 1e3 * NOISE_MM, "um", 1.0)])
    geo = identify_serial(ur5, camp, SerialIdentificationOptions(tool_offset_mm=TOOL, model="dh", budget=budget))
    lack = geo.fit.lack_of_fit_mm
    assert 0.1 < lack < 0.25, lack  # mm: the residuals' sigma less the 2 um readings
    assert any(n.startswith("lack of fit") and "the budget" in n for n in geo.fit.notes), geo.fit.notes
    e, u = _unseen_points(geo, truth)
    u_fit = np.sqrt(np.maximum(u ** 2 - lack ** 2, 0.0))
    assert _rms(e) / _rms(u_fit) > 2.0  # (what the covariance alone would state)
    assert 0.5 <= _rms(e) / _rms(u) <= 1.5, _rms(e) / _rms(u)
    assert np.mean(np.abs(e) <= 3 * u) >= 0.95


def test_the_scara_takes_the_prior_when_asked_and_its_uncertainty_re_adds_it(tmp_path):
    """The engine's prior on the SCARA's maps too (off by default there: the paper's campaigns command every node
    both ways): stated in the result, and ``olti uncertainty`` propagates the same estimator -- a heavy stated
    weight narrows the maps' u against the same result stripped of its prior."""
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    campaign = root / "data" / "paper000" / "campaign.csv"

    olti_sub("identify", campaign, "--model", "errormap", "--smoothing", "auto", "--out", tmp_path / "auto.json",
             expect=0)
    auto = json.loads((tmp_path / "auto.json").read_text())["smoothing"]
    assert auto["method"] == "restricted maximum likelihood" and auto["weight"] > 0
    olti_sub("identify", campaign, "--model", "errormap", "--smoothing", "1e9", "--out", tmp_path / "r.json", expect=0)
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["smoothing"]["method"] == "given" and res["smoothing"]["weight"] == 1e9
    stripped = dict(res)
    stripped.pop("smoothing")
    (tmp_path / "stripped.json").write_text(json.dumps(stripped))

    def u(result):
        olti_sub("uncertainty", tmp_path / result, campaign, "--method", "linear", "--out", tmp_path / f"u_{result}",
                 "--force", expect=0)
        return np.median(json.loads((tmp_path / f"u_{result}").read_text())["error_map"]["J2"]["forward_deg"])

    assert u("r.json") < 0.85 * u("stripped.json")


def test_a_joint_flipped_by_180_degrees_is_named_as_such(ur5):
    """SerialPositionModel.implausible: a map value or offset near a multiple of 180 deg is a flipped joint (the
    mirror pose of the arm), named so; hundreds of degrees elsewhere stay the radians hint."""
    from olti_drake.model.serial import build_position_model

    c = synthetic_campaign(synthetic_truth(ur5, 1), 40, 1)
    for kind in ("dh", "errormap"):
        model = build_position_model(ur5, c.commands, c.dirs, kind=kind, tool_offset_mm=TOOL)
        x = model.start_vector()
        i = model.n_dense if kind == "errormap" else list(model.names).index("elbow_joint_offset_deg")
        x[i] = -179.2
        (flip,) = model.implausible(x)
        assert model.names[i] in flip and "turned by 180 deg" in flip and "flipped" in flip
        x[i] = 57.3 * 2  # (2 rad read as degrees)
        (rad,) = model.implausible(x)
        assert "radians" in rad and "flipped" not in rad
