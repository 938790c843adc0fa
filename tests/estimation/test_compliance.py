"""Joint compliance under gravity (``--compliance``): θ_i = θ*_i + Δθ_i + c_i·τ_i(θ*), τ from the model file's
masses by Drake's CalcGravityGeneralizedForces."""

import dataclasses
import os

import numpy as np
import pytest

from olti_drake.estimation.calibration import Calibration
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.model.chain import gravity_torques, load_serial_chain
from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign,
                                     synthetic_truth)
from olti_calls import error_line, olti_sub

TOOL = (40.0, -25.0, 60.0)
RANGES = np.array([[-90, 90], [-170, -10], [-120, 120], [-90, 90], [-60, 150], [-180, 180]], float)
C_TRUE = np.array([0.0, 2e-4, 3e-4, 0.0, 0.0, 0.0])  # deg/(N·m): ~10 mdeg at the shoulder's ~50 N·m


@pytest.fixture(scope="module")
def chain():
    return load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")


def test_gravity_pulls_the_outstretched_arm_down(chain):
    """Horizontal arm: shoulder and elbow carry torque, the vertical base axis none; a deflection +c·τ lowers
    the tool (Drake's sign: the generalized force gravity exerts). Arm straight up: no torque."""
    out = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    up = np.array([[0.0, -90.0, 0.0, -90.0, 0.0, 0.0]])
    tau = gravity_torques(chain, out)[0]
    assert abs(tau[0]) < 1e-9 and abs(tau[1]) > 20 and abs(tau[2]) > 5
    assert np.abs(gravity_torques(chain, up)).max() < 1e-6
    p0 = chain.positions(out)[0]
    p1 = chain.positions(out + 1e-3 * tau)[0]
    assert p1[2] < p0[2] - 1e-3
    heavier = gravity_torques(chain, out, payload_kg=2.0, tool_offset_mm=TOOL)[0]
    assert heavier[1] * tau[1] > 0 and abs(heavier[1]) > abs(tau[1])


def test_compliance_columns_are_the_derivative(chain):
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 40, seed=5, ranges_deg=RANGES)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="dh", tool_offset_mm=TOOL, compliance=True)
    names = [n for n in model.names if n.endswith("_compliance_deg_per_Nm")]
    assert names == ["shoulder_lift_joint_compliance_deg_per_Nm", "elbow_joint_compliance_deg_per_Nm"]
    dropped = dict(model.dropped)
    assert "vertical axis" in dropped["shoulder_pan_joint_compliance_deg_per_Nm"]
    x = model.start_vector()
    x[model.names.index(names[0])] = 1e-4
    _, jac = model.jacobian(camp.commands, camp.dirs, x)
    J = jac.tocsr().toarray()
    for name in names:
        i = model.names.index(name)
        h = 1e-6
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        fd = (model.positions(camp.commands, camp.dirs, xp) - model.positions(camp.commands, camp.dirs, xm)) / (2 * h)
        assert np.allclose(J[:, i], fd.ravel(), rtol=1e-6, atol=1e-6)


def test_compliance_recovered_within_its_uncertainty_from_a_truth_off_the_model_family(chain):
    """Truth: harmonic joint deviations with backlash (not in the 15° map family) and compliant shoulder and
    elbow; 1 µm noise. The compliance is recovered within 3 standard uncertainties (the residual-based u of
    the fit) and the residual drops against the model without compliance."""
    truth = dataclasses.replace(synthetic_truth(chain, seed=3, tool_offset_mm=TOOL), compliance_deg_per_Nm=C_TRUE)
    camp = synthetic_campaign(truth, 400, seed=4, ranges_deg=RANGES, noise_mm=0.001)
    rms = {}
    for comp in (False, True):
        model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=15,
                                     tool_offset_mm=TOOL, compliance=comp)
        meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                                   camp.displacement_mm, truth.stations_mm + 2.0, truth.dead_paths_mm)
        fit = Calibration(meas, gauge=find_gauge(meas)).fit()
        rms[comp] = np.sqrt(np.mean(fit.residuals ** 2))
        if comp:
            for j, joint in enumerate(chain.joint_names):
                name = f"{joint}_compliance_deg_per_Nm"
                if name in meas.names:
                    i = meas.names.index(name)
                    assert abs(fit.x[i] - C_TRUE[j]) < 3 * fit.std[i], (name, fit.x[i], fit.std[i])
                    assert fit.std[i] < 0.2 * C_TRUE[j]
    assert rms[True] < 0.85 * rms[False]


def test_a_result_with_compliance_loads_back_to_the_same_model(chain, tmp_path):
    from olti_drake.io.serial_io import load_serial_result, serial_result_dict, write_serial_result

    truth = dataclasses.replace(synthetic_truth(chain, seed=3, tool_offset_mm=TOOL), compliance_deg_per_Nm=C_TRUE)
    camp = synthetic_campaign(truth, 120, seed=6, ranges_deg=RANGES, noise_mm=0.001)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="dh", tool_offset_mm=TOOL, compliance=True)
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station, camp.displacement_mm,
                               truth.stations_mm, truth.dead_paths_mm)
    cal = Calibration(meas, gauge=find_gauge(meas))
    fit = cal.fit()
    path = tmp_path / "result.json"
    write_serial_result(path, serial_result_dict(kind="dh", robot_file="ur5", measurement=meas, fit=fit,
                                                 gauge=cal.gauge))
    back = load_serial_result(path).model
    assert back.names == model.names
    p = model.positions(camp.commands, camp.dirs, fit.x[:model.n_params])
    assert np.allclose(back.positions(camp.commands, camp.dirs), p, atol=1e-9)


def test_dead_path_drift_is_identified_from_reading_times(chain):
    """A linear drift of every station's dead path during the campaign (mm/h) is recovered within 3u and resolved
    (u well below the drift); the residual does not grow with the drift term. The truth's maps are harmonic (not
    in the 15° family), so the residual is dominated by that, not by the drift."""
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 300, seed=4, ranges_deg=RANGES, noise_mm=0.0005)
    n = len(camp.station)
    time_h = np.arange(n) / n * 4.0  # a 4-hour campaign, station by station
    v_true = np.array([0.02, -0.015, 0.012, 0.025])  # mm/h (thermal drift of a long campaign)
    ref = np.array([time_h[camp.station == j].mean() for j in range(4)])
    readings = camp.displacement_mm - v_true[camp.station] * (time_h - ref[camp.station])
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=15,
                                 tool_offset_mm=TOOL)
    rms = {}
    for drift in (False, True):
        meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station, readings,
                                   truth.stations_mm + 2.0, truth.dead_paths_mm, time_h=time_h if drift else None)
        fit = Calibration(meas, gauge=find_gauge(meas)).fit()
        rms[drift] = np.sqrt(np.mean(fit.residuals ** 2))
        if drift:
            i = [meas.names.index(f"drift_{j}_mm_per_h") for j in range(4)]
            assert np.all(np.abs(fit.x[i] - v_true) < 3 * fit.std[i]), (fit.x[i], fit.std[i])
            assert np.all(fit.std[i] < 0.25 * np.abs(v_true)), fit.std[i]
            assert meas.layout(fit.x)["drift_mm_per_h"] == pytest.approx(list(fit.x[i]))
    assert rms[True] <= rms[False]


def test_cli_compliance_and_drift(chain, tmp_path):
    """olti identify --robot ur5 --compliance --drift on a campaign with time_s: the result names the compliance
    and drift parameters, olti predict reproduces the readings (drift included) within a few µm, olti report
    shows the drift; --drift without time_s is one line naming the column."""
    import json

    from olti_drake.io.serial_io import write_serial_campaign

    truth = dataclasses.replace(synthetic_truth(chain, seed=3, tool_offset_mm=TOOL), compliance_deg_per_Nm=C_TRUE)
    camp = synthetic_campaign(truth, 250, seed=4, ranges_deg=RANGES, noise_mm=0.0005)
    n = len(camp.station)
    time_s = np.arange(n) * 4.0 * 3600 / n
    v = np.array([0.02, -0.015, 0.012, 0.025])
    ref = np.array([time_s[camp.station == j].mean() / 3600 for j in range(4)])
    readings = camp.displacement_mm - v[camp.station] * (time_s / 3600 - ref[camp.station])
    path = tmp_path / "campaign.csv"
    write_serial_campaign(path, camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=readings, extra={"time_s": time_s})

    run = olti_sub("identify", path, "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm", "40,-25,60",
                   "--model", "errormap", "--compliance", "--drift", "--out", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    res = json.loads((tmp_path / "r.json").read_text())
    assert "elbow_joint_compliance_deg_per_Nm" in res and len(res["drift_mm_per_h"]) == 4
    assert np.allclose(res["drift_mm_per_h"], v, atol=3 * np.asarray(res["uncertainty"]["drift_mm_per_h"]) + 1e-4)
    run = olti_sub("predict", tmp_path / "r.json", path, "--out", tmp_path / "p.csv")
    assert run.returncode == 0, run.stderr
    lines = [ln for ln in (tmp_path / "p.csv").read_text().splitlines() if not ln.startswith("#")]
    head = lines[0].split(",")
    rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    miss = rows[:, head.index("predicted_displacement_mm")] - rows[:, head.index("displacement_mm")]
    assert np.sqrt(np.mean(miss ** 2)) < 3 * res["residual_rms_mm"] + 1e-4
    run = olti_sub("report", tmp_path / "r.json", "--out", tmp_path / "rep")
    assert run.returncode == 0, run.stderr
    assert "dead-path drift 3" in (tmp_path / "rep" / "report.html").read_text()
    plain = tmp_path / "plain.csv"
    write_serial_campaign(plain, camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=readings)
    run = olti_sub("identify", plain, "--robot", "ur5", "--tool-frame", "tool0", "--model", "dh", "--drift",
                   "--out", tmp_path / "r2.json")
    error_line(run.returncode, run.stderr, "'time_s'")
