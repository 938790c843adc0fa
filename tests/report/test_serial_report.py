"""The HTML report of an N-joint robot result (issue 13, item 8): maps per joint with error bars, ISO 230-2
statistics per joint, residuals, geometric parameters and identifiability notes."""

import json
import os
import re

import numpy as np
import pytest

from olti_drake.estimation.calibration import Calibration
from olti_drake.io.outputs import write_json
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import serial_result_dict, serial_truth_dict, write_serial_campaign, write_serial_result
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign,
                                     synthetic_truth)
from olti_calls import error_line, olti_sub

RANGES = np.array([[-90.0, 90.0]] * 6)
TOOL = (40.0, -25.0, 60.0)


def _identify(out, directions="random", kind="errormap"):
    """A UR5 campaign of a harmonic truth (not in the model family), identified through the Python API."""
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 200, seed=4, ranges_deg=RANGES, noise_mm=0.001, directions=directions)
    model = build_position_model(chain, camp.commands, camp.dirs, kind=kind, grid_step_deg=30, tool_offset_mm=TOOL)
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station, camp.displacement_mm,
                               truth.stations_mm + 5.0, truth.dead_paths_mm)
    cal = Calibration(meas, gauge=find_gauge(meas))
    fit = cal.fit()
    os.makedirs(out, exist_ok=True)
    paths = {n: os.path.join(out, n) for n in ("campaign.csv", "result.json", "truth.json")}
    write_serial_campaign(paths["campaign.csv"], camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    write_serial_result(paths["result.json"], serial_result_dict(kind=kind, robot_file="ur5", measurement=meas,
                                                                 fit=fit, gauge=cal.gauge))
    write_json(paths["truth.json"], serial_truth_dict(truth, "ur5"))
    return paths, chain, fit


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    return _identify(str(tmp_path_factory.mktemp("ur5")))


def test_report_shows_every_joint_parameter_and_residual(identified, tmp_path):
    paths, chain, fit = identified
    out = tmp_path / "rep"
    run = olti_sub("report", paths["result.json"], "--campaign", paths["campaign.csv"], "--truth", paths["truth.json"],
                   "--out", str(out))
    assert run.returncode == 0, run.stderr
    page = (out / "report.html").read_text()
    raw = json.loads(open(paths["result.json"]).read())
    for joint in chain.joint_names:  # an ISO 230-2 table per joint
        assert re.search(rf"<h3[^>]*>{re.escape(joint)} \(", page), joint  # (stamped with its data file's hash)
    for name in [k for k in raw if k.endswith(("_dx_mm", "_drz_deg"))][:5]:
        assert f">{name}<" in page
    for d in raw["dropped"]:
        assert d["parameter"] in page
    # The residual RMS the page states is the result's: the model and the stations were rebuilt right.
    rms = float(re.search(r"RMS ([0-9.]+) µm\.", page).group(1))
    assert rms == pytest.approx(1e3 * raw["residual_rms_mm"], rel=0.02, abs=0.02)
    iso = json.loads((out / "iso230.json").read_text())
    assert list(iso["axes"]) == list(chain.joint_names)
    # The reversal B_i of the first node of joint 2 is forward - reverse of the result's map.
    m = raw["error_map"][chain.joint_names[1]]
    assert iso["axes"][chain.joint_names[1]]["nodes"]["reversal_deg"][0] == pytest.approx(m["forward_deg"][0] - m["reverse_deg"][0])
    for name in ("fig_maps.png", "fig_reversal.png", "fig_residuals.png"):
        assert (out / name).stat().st_size > 10_000


def test_one_directional_result_says_it_has_no_reversal(tmp_path):
    paths, chain, _ = _identify(str(tmp_path / "one"), directions=False)
    run = olti_sub("report", paths["result.json"], "--out", str(tmp_path / "rep"))
    assert run.returncode == 0, run.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "One-directional map(s)" in page and "no reversal" in page
    assert not (tmp_path / "rep" / "fig_reversal.png").exists()


def test_another_campaign_or_a_mismatched_uncertainty_is_refused_in_one_line(identified, tmp_path):
    paths, chain, _ = identified
    short = tmp_path / "short.csv"
    lines = open(paths["campaign.csv"]).read().splitlines()
    head = [ln for ln in lines if not ln.startswith("#")][0]
    body = [ln for ln in lines if not ln.startswith("#")][1:]
    station_col = head.split(",").index("station")
    short.write_text("\n".join([head] + [ln for ln in body if ln.split(",")[station_col] != "3"]) + "\n")
    run = olti_sub("report", paths["result.json"], "--campaign", str(short), "--out", str(tmp_path / "a"))
    error_line(run.returncode, run.stderr, "not the campaign of this result")
    raw = json.loads(open(paths["result.json"]).read())
    unc = dict(raw["uncertainty"], format="olti-uncertainty/1")
    unc["tool_offset_mm"] = [1.0, 2.0]
    bad = tmp_path / "unc.json"
    bad.write_text(json.dumps(unc))
    run = olti_sub("report", paths["result.json"], str(bad), "--out", str(tmp_path / "b"))
    error_line(run.returncode, run.stderr, "tool_offset_mm")
