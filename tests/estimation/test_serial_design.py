"""Station placement design in 3D for robots loaded from a model file (issue 13, item 7)."""

import json
import os

import numpy as np
import pytest
import scipy.linalg
import scipy.spatial

from olti_drake.errors import InputError
from olti_drake.estimation.serial_design import (StationInformation, candidate_points, design_stations,
                                                 evaluate_layout, gauge_rows, load_boxes, workspace_poses)
from olti_drake.estimation.serial_plan import readable
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign, synthetic_truth
from olti_calls import error_line, olti_sub

TOOL = (40.0, -25.0, 60.0)
U_READING = 0.002


@pytest.fixture(scope="module")
def setup():
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 250, seed=4, ranges_deg=np.array([[-90.0, 90.0]] * 6))
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=45,
                                 tool_offset_mm=TOOL)
    A, _ = gauge_rows(model, camp.commands, camp.dirs, truth.stations_mm)
    info = StationInformation(model, camp.commands, camp.dirs, U_READING, workspace_poses(model, 60, 1), gauge_rows=A)
    return chain, truth, camp, model, info


def _full_problem_u(meas, info):
    """u (mm, k = 1) of the workspace tool points from the covariance of the whole distance problem ``meas``
    (stations and dead paths unknown, the gauge of find_gauge), readings of u U_READING."""
    _, J = meas.residuals(meas.start_vector())
    Z = scipy.linalg.null_space(find_gauge(meas).A)
    cov = U_READING ** 2 * Z @ np.linalg.inv(Z.T @ (J.T @ J).toarray() @ Z) @ Z.T
    n, G = info.model.n_params, info.workspace_jacobian
    return np.sqrt(np.sum((G @ cov[:n, :n]) * G, axis=1).reshape(-1, 3).sum(axis=1))


def _design_cli(result, regions_text, tmp_path, *options):
    """``olti design`` of ``result`` on a regions file of ``regions_text``: (the run, its document or None)."""
    regions, out = tmp_path / "regions.yaml", tmp_path / "design.json"
    regions.write_text(regions_text)
    run = olti_sub("design", result, "--regions", regions, *options, "--out", out, "--force")
    return run, (json.loads(out.read_text()) if run.returncode == 0 else None)


def test_predicted_u_equals_the_full_problem_with_stations_unknown(setup):
    """The Schur-complement information summed over stations gives the same tool-point u as the covariance of
    the whole distance problem (stations and dead paths unknown, the gauge of find_gauge), to 1e-6."""
    chain, truth, camp, model, info = setup
    P = truth.stations_mm
    ok = readable(chain, camp.commands, P, info.rules, info.tool_offset)
    pose, st = np.nonzero(ok)
    meas = DistanceMeasurement(model, camp.commands[pose], camp.dirs[pose], st, np.zeros(len(st)), P, np.zeros(len(P)))
    blocks = [info.block(p)[0] for p in P]
    assert np.allclose(info.position_u(sum(blocks)), _full_problem_u(meas, info), rtol=1e-6)
    assert [info.block(p)[1] for p in P] == list(ok.sum(axis=0))


def test_design_beats_the_start_and_a_clustered_layout(setup):
    chain, truth, camp, model, info = setup
    cand = candidate_points(np.array([[[-1500, 1500], [-1500, 1500], [-400, -400]]]), 750.0)
    d = design_stations(info, cand, 4, seed=0, starts=2, max_sweeps=3, min_separation_mm=300)
    clustered = evaluate_layout(info, [[1500, 1500, -400], [1500, 750, -400], [750, 1500, -400], [750, 750, -400]])
    assert d.cost_mm < clustered["cost_mm"]
    assert d.cost_mm <= evaluate_layout(info, truth.stations_mm)["cost_mm"] * 1.5  # same league as a spread layout
    assert np.min(scipy.spatial.distance.pdist(d.stations_mm)) >= 300
    again = design_stations(info, cand, 4, seed=0, starts=2, max_sweeps=3, min_separation_mm=300)
    assert np.array_equal(again.stations_mm, d.stations_mm)  # seeded


def test_bad_regions_and_too_few_candidates_are_one_line(setup, tmp_path):
    chain, truth, camp, model, info = setup
    bad = tmp_path / "r.yaml"
    bad.write_text("regions:\n  - {x_mm: [0, 100], y_mm: [0, 100]}\n")
    with pytest.raises(InputError, match=r"regions\[0\]\.z_mm"):
        load_boxes(bad)
    with pytest.raises(InputError, match="stations are needed"):
        design_stations(info, np.array([[1500.0, 0, -400], [0, 1500.0, -400]]), 4)


def test_cli_design_of_a_serial_result(setup, tmp_path):
    from olti_drake.estimation.calibration import Calibration
    from olti_drake.io.serial_io import serial_result_dict, write_serial_result

    chain, truth, camp, model, info = setup
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station, camp.displacement_mm,
                               truth.stations_mm, truth.dead_paths_mm)
    cal = Calibration(meas, gauge=find_gauge(meas))
    result = tmp_path / "result.json"
    write_serial_result(result, serial_result_dict(kind="errormap", robot_file="ur5", measurement=meas, fit=cal.fit(),
                                                   gauge=cal.gauge))
    floor = "regions:\n  - {x_mm: [-1500, 1500], y_mm: [-1500, 1500], z_mm: -400}\n"
    run, doc = _design_cli(result, floor, tmp_path, "--step-mm", "1500", "--starts", "1", "--max-sweeps", "2",
                           "--workspace-poses", "40")
    assert run.returncode == 0, run.stderr
    assert doc["format"] == "olti-design/1" and np.shape(doc["stations_mm"]) == (4, 3)
    assert doc["designed"]["cost_mm"] <= doc["current"]["cost_mm"] * 2 and "improvement" in doc
    run, _ = _design_cli(result, floor, tmp_path, "--reflectors", "3")
    error_line(run.returncode, run.stderr, ">= 4")


def test_a_planar_robot_is_designed_in_its_plane(tmp_path):
    """A planar result (the SCARA of 000 as models/scara.sdf, stations in its plane) is designed in that plane:
    the station information with two in-plane coordinates and a dead path per station gives the tool-point u
    of the whole planar distance problem (DistanceMeasurement(plane=...), its gauge) to 1e-6; the readability
    is the SCARA design's (a steered beam, the base radius, the clearance); through the command line 3 stations
    suffice, the candidates lie in the plane, and regions that do not reach it are refused in one line."""
    from olti_drake.estimation.serial_design import candidates_in_plane, planar_readable
    from olti_drake.model.chain import plane_frame, robot_plane

    root = os.path.dirname(PACKAGE_DIR)
    campaign = os.path.join(root, "data", "paper000", "campaign.csv")
    result = tmp_path / "scara.json"
    olti_sub("identify", campaign, "--robot", "scara", "--tool-frame", "beam", "--model", "errormap",
             "--grid-step-deg", "20", "--out", result, expect=0)
    from olti_drake.io.serial_io import load_serial_result

    res = load_serial_result(result, outside="clamp")
    model, P = res.model, res.stations_mm
    plane = robot_plane(model.chain, model.chain_params)
    assert plane == 2 and model.planar_reduced
    plan, dirs = workspace_poses(model, 200, 5)
    A, _ = gauge_rows(model, plan, dirs, P, plane=plane)
    info = StationInformation(model, plan, dirs, U_READING, workspace_poses(model, 50, 6), gauge_rows=A, plane=plane)
    ok = np.column_stack([planar_readable(info.p, s, plane, model.chain.fixed_mm[0][:3, 3], 40.0, 50.0, info._arm)
                          for s in P])
    assert ok.all()  # (the paper's reflectors: in front, beyond the reach, no beam past the base)
    behind, inside = ([planar_readable(info.p, np.array(s), plane, model.chain.fixed_mm[0][:3, 3], 40.0, 50.0,
                                       info._arm) for s in ([-800.0, 0, 360], [300.0, 0, 360])])
    assert 0 < behind.sum() < len(behind) and not inside.any()  # the base column hides some; in the arm's way
    pose, st = np.nonzero(ok)
    meas = DistanceMeasurement(model, plan[pose], dirs[pose], st, np.zeros(len(st)), P, np.zeros(len(P)), plane=plane)
    assert np.allclose(info.position_u(sum(info.block(p)[0] for p in P)), _full_problem_u(meas, info), rtol=1e-6)
    # candidates: half a step from the plane, moved onto it; none near it: one line
    cand = candidates_in_plane(np.array([[900.0, 0, 340], [900.0, 100, 500], [800, 0, 380]]), plane, 360.0, 50.0)
    assert np.array_equal(cand, [[800.0, 0, 360], [900.0, 0, 360]])
    with pytest.raises(InputError, match="robot's plane"):
        candidates_in_plane(np.array([[900.0, 0, 0]]), plane, 360.0, 50.0)
    run, doc = _design_cli(result, "regions:\n  - {x_mm: [650, 900], y_mm: [-900, 350], z_mm: [0, 600]}\n",
                           tmp_path, "--step-mm", "125", "--starts", "1", "--max-sweeps", "2", "--workspace-poses", "40")
    assert run.returncode == 0, run.stderr
    assert "in the planar robot's plane" in run.stdout
    designed = np.array(doc["stations_mm"])
    assert designed.shape == (3, 3) and np.allclose(designed @ plane_frame(plane)[0], 360.0)
    assert doc["designed"]["cost_mm"] <= doc["current"]["cost_mm"] * 1.5
    run, _ = _design_cli(result, "regions:\n  - {x_mm: [650, 900], y_mm: [-900, 350], z_mm: [0, 100]}\n", tmp_path)
    error_line(run.returncode, run.stderr, "robot's plane")
