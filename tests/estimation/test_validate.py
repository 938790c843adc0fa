"""Issue 23, item 3: model selection a user can trust (``olti validate``, estimation.validation.cross_validate).

K-fold cross-validation by pose of an N-joint robot's candidate models on random-pose UR5 campaigns whose truth is
not in the model family (harmonic joint deviations with backlash, model.serial.synthetic_truth): a small tracker
set (80 points) gets the geometric model with a reason; a richer distance campaign an error map; the folds do not
depend on the order of the rows; the CLI writes CV.json and refuses bad input in one line; and an identification
does not depend on the order of the rows (<= 1 um of predicted tool point)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial
from olti_drake.estimation.validation import (cross_validate, fit_solution, fold_of_rows, parse_models,
                                              predict_rows, recommend)
from olti_drake.io.serial_io import SerialCampaign, load_robot, write_serial_campaign
from olti_drake.model.serial import synthetic_campaign, synthetic_truth
from olti_calls import error_line, olti_in

TOOL = (40.0, -25.0, 60.0)
NOISE_MM = 0.0005
#: +-90 deg on every joint: 30 deg map nodes at the range ends, reached from inside in both directions.
RANGES = np.tile([-90.0, 90.0], (6, 1))


@pytest.fixture(scope="module")
def chain():
    return load_robot("ur5", "tool0")


@pytest.fixture(scope="module")
def truth(chain):
    return synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)


def distance_campaign(camp, source="d.csv") -> SerialCampaign:
    m = len(camp.station)
    return SerialCampaign("distance", camp.distance_commands, camp.distance_dirs, np.arange(m) + 2, source,
                          station=camp.station, displacement_mm=camp.displacement_mm)


def point_campaign(camp, source="p.csv") -> SerialCampaign:
    m = len(camp.commands)
    return SerialCampaign("point", camp.commands, camp.dirs, np.arange(m) + 2, source, points_mm=camp.points_mm)


@pytest.fixture(scope="module")
def rich(truth):
    """100 poses x 4 stations, random directions, +-90 deg: 400 distance readings."""
    return distance_campaign(synthetic_campaign(truth, 100, seed=4, ranges_deg=RANGES, noise_mm=NOISE_MM))


def options(**kw):
    return SerialIdentificationOptions(tool_offset_mm=TOOL, **kw)


#: The maps' own roughness prior off (where the engine has the option), for a plain weak ridge instead.
NO_SMOOTHING = {"smoothing": "off"} if "smoothing" in {f.name for f in dataclasses.fields(
    SerialIdentificationOptions)} else {}


@pytest.mark.parametrize("case", ["small deviations", "over-fitted maps"])
def test_a_small_tracker_set_gets_the_geometric_model_and_a_reason(chain, case):
    # An ordinary random-pose tracker set over the UR5's whole joint ranges: 80 points. "small deviations": 20 um
    # noise, a truth whose joint deviations (0.5 mdeg harmonics and backlash; location errors 0.2 mm, 0.02 deg) 80
    # points cannot resolve: a map is refused or no better than the geometric model on held-out poses.
    # "over-fitted maps": 10 um noise, 20 mdeg deviations, maps fitted with the weak --regularize prior and no
    # smoothing: fitted in every fold, and worse than the geometric model on the held-out poses.
    small = case == "small deviations"
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL, **(dict(deviation_mdeg=0.5, backlash_mdeg=0.25)
                                                                  if small else {}))
    camp = point_campaign(synthetic_campaign(truth, 80, seed=5, noise_mm=0.02 if small else 0.01))
    o = options() if small else options(regularize=True, **NO_SMOOTHING)
    # (the over-fitted case with one map grid: its regularized folds take most of this file's time)
    models = "dh,errormap:30,errormap:15" if small else "dh,errormap:30"
    cv = cross_validate(chain, camp, o, folds=5, models=models, seed=0)
    if not small:
        assert all(m["n_refused"] == 0 and m["mean_rms_mm"] > cv["models"][0]["mean_rms_mm"]
                   for m in cv["models"][1:]), [(m["name"], m["mean_rms_mm"]) for m in cv["models"]]
    assert cv["recommended"] == "dh", cv["reason"]
    assert cv["reason"].startswith(("dh ", "errormap")) and len(cv["reason"]) > 40
    dh = cv["models"][0]
    assert dh["n_refused"] == 0 and len(dh["fold_rms_mm"]) == 5 and dh["mean_rms_mm"] < 0.5
    assert dh["std_rms_mm"] > 0 and abs(dh["se_rms_mm"] - dh["std_rms_mm"] / 5 ** 0.5) < 1e-12
    for m in cv["models"][1:]:  # a map is refused (and says why), or no better than dh by the rule
        assert (m["n_refused"] > 0 and all(r["reason"] for r in m["refused"])
                or m["mean_rms_mm"] + m["se_rms_mm"] >= dh["mean_rms_mm"])
    assert "one-standard-error" in cv["rule"] and "3D point errors" in cv["metric"]
    assert sum(cv["fold_poses"]) == 80 and max(cv["fold_poses"]) - min(cv["fold_poses"]) <= 1


def test_a_richer_distance_campaign_gets_an_error_map(chain, rich):
    cv = cross_validate(chain, rich, options(), folds=4, models="dh,errormap:30", seed=0)
    dh, em = cv["models"]
    assert dh["n_refused"] == em["n_refused"] == 0, (dh["refused"], em["refused"])
    assert em["mean_rms_mm"] < 0.8 * dh["mean_rms_mm"], (dh["mean_rms_mm"], em["mean_rms_mm"])
    assert em["parameters"] > dh["parameters"]
    assert cv["recommended"] == "errormap:30" and "lowest mean held-out RMS" in cv["reason"]
    assert "distance residuals" in cv["metric"] and cv["campaign"]["poses"] == 100
    assert cv["campaign"]["readings"] == 400 and sum(cv["fold_readings"]) == 400
    json.dumps(cv, allow_nan=False)  # (finite numbers only: null where a value does not exist)


def test_folds_are_by_pose_and_independent_of_the_order_of_the_rows(rich):
    fold = fold_of_rows(rich, 5, seed=0)
    perm = np.random.default_rng(1).permutation(len(rich))
    shuffled = fold_of_rows(rich.subset(perm), 5, seed=0)
    assert np.array_equal(shuffled, fold[perm])
    key = [tuple(r) for r in np.hstack([rich.commands, rich.dirs])]
    by_pose = {}
    for k, f in zip(key, fold):
        assert by_pose.setdefault(k, f) == f  # every row of a pose in one fold
    assert sorted(np.bincount(list(by_pose.values()))) == [20] * 5
    assert not np.array_equal(fold_of_rows(rich, 5, seed=1), fold)  # the seed decides
    with pytest.raises(InputError, match="at least 2 folds"):
        fold_of_rows(rich, 1)
    with pytest.raises(InputError, match="100 distinct poses"):
        fold_of_rows(rich, 101)


def test_the_one_standard_error_rule_and_refusals():
    def m(name, params, mean, se, refused=0):
        return dict(name=name, parameters=params, mean_rms_mm=None if refused else mean,
                    se_rms_mm=None if refused else se, n_refused=refused, fold_rms_mm=[mean] * 5,
                    refused=[{"fold": 0, "reason": "not identifiable: x -- hint"}] * refused)
    assert recommend([m("dh", 40, 0.105, 0.01), m("errormap:30", 140, 0.1, 0.01)])[0] == "dh"
    assert recommend([m("dh", 40, 0.2, 0.01), m("errormap:30", 140, 0.1, 0.01)])[0] == "errormap:30"
    name, why = recommend([m("dh", 40, 0.2, 0.01), m("errormap:15", 240, 0.01, 0.001, refused=2)])
    assert name == "dh" and "errormap:15 refused in 2 of 5 folds (not identifiable: x)" in why
    assert recommend([m("errormap:15", 240, 0.01, 0.001, refused=5)])[0] is None
    assert [c.name for c in parse_models("dh,errormap,errormap:7.5,compliance,errormap:30+drift", 20)] == [
        "dh", "errormap:20", "errormap:7.5", "dh+compliance", "errormap:30+drift"]
    for bad in ("dh,nope", "errormap:-1", "dh:15", "dh,dh", "dh+foo", ""):
        with pytest.raises(InputError, match="--models"):
            parse_models(bad)


def test_a_held_out_command_beyond_the_training_grid_is_clamped_and_counted(chain, truth, rich):
    ident = fit_solution(chain, rich, options(model="errormap", grid_step_deg=30.0))
    held = distance_campaign(synthetic_campaign(truth, 3, seed=7, ranges_deg=RANGES * 1.2))
    pred, clamped = predict_rows(ident, held)
    grid = ident.model.maps[0].emap.grid_deg
    assert np.all(np.isfinite(pred)) and np.any(clamped)
    outside = np.any([(held.commands[:, j] < m.emap.grid_deg[0]) | (held.commands[:, j] > m.emap.grid_deg[-1])
                      for j, m in zip(ident.model.map_joints, ident.model.maps)], axis=0)
    assert np.array_equal(clamped, outside) and grid[-1] == 90.0
    assert np.sqrt(np.mean((pred - held.displacement_mm) ** 2)) < 1.0  # (a prediction, not a runaway)


@pytest.mark.parametrize("model", ["dh", "errormap"])
def test_an_identification_does_not_depend_on_the_order_of_the_rows(chain, truth, model):
    camp = distance_campaign(synthetic_campaign(truth, 60, seed=8, ranges_deg=RANGES, noise_mm=NOISE_MM))
    shuffled = camp.subset(np.random.default_rng(2).permutation(len(camp)))
    o = SerialIdentificationOptions(model=model, grid_step_deg=30.0)  # (the start's tool point on the axis)
    a, b = identify_serial(chain, camp, o), identify_serial(chain, shuffled, o)
    poses = synthetic_campaign(truth, 40, seed=9, ranges_deg=RANGES * 0.9)
    pa = a.model.positions(poses.commands, poses.dirs, a.fit.x[:a.model.n_params])
    pb = b.model.positions(poses.commands, poses.dirs, b.fit.x[:b.model.n_params])
    assert np.max(np.linalg.norm(pa - pb, axis=1)) <= 1e-3  # mm


# -- the command line ----------------------------------------------------------------------------------------------
def test_the_command_line_writes_cv_json_and_refuses_bad_input_in_one_line(tmp_path, capsys, truth):
    camp = synthetic_campaign(truth, 30, seed=10, ranges_deg=RANGES, noise_mm=NOISE_MM)
    path = tmp_path / "campaign.csv"
    write_serial_campaign(path, camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    robot = ("--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm=40,-25,60")
    out = tmp_path / "cv.json"
    code, text, err = olti_in("validate", path, *robot, "--folds", "3", "--models", "dh", "--out", out, capsys=capsys)
    assert code == 0, err
    assert "recommended: dh" in text and f"wrote {out}" in text
    cv = json.loads(out.read_text())
    assert cv["format"] == "olti-cv/1" and cv["folds"] == 3 and cv["recommended"] == "dh"
    assert cv["robot"] == {"file": "ur5", "tool_frame": "tool0"} and cv["options"]["tool_offset_mm"] == list(TOOL)
    assert [m["name"] for m in cv["models"]] == ["dh"] and len(cv["models"][0]["fold_rms_mm"]) == 3
    bad = tmp_path / "bad.json"
    for argv, needles in ((("--folds", "1"), ("--folds", ">= 2")), (("--folds", "31"), ("30 distinct poses",)),
                          (("--models", "dh,nope"), ("unknown model 'nope'",)),
                          (("--models", "drift"), ("time_s",))):
        error_line(*olti_in("validate", path, *robot, *argv, "--out", bad, capsys=capsys)[::2], *needles)
    error_line(*olti_in("validate", path, "--out", bad, capsys=capsys)[::2], "SCARA campaign", "--robot")
    error_line(*olti_in("identify", path, "--model", "dh", "--cv", "3", "--out", bad, capsys=capsys)[::2],
                   "--cv needs --robot")
    assert not bad.exists()
    # olti identify --cv K: the validation printed, then the model asked identified and written as usual
    result = tmp_path / "result.json"
    code, text, err = olti_in("identify", path, *robot, "--model", "dh", "--cv", "3", "--out", result, capsys=capsys)
    assert code == 0, err
    assert text.index("3-fold cross-validation by pose") < text.index("model dh of") and "recommended:" in text
    assert json.loads(result.read_text())["kind"] == "serial"
