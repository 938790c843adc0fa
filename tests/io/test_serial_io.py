"""Files of N-joint serial robots (olti_drake.io.serial_io): campaigns written and read back, every
malformed campaign refused in one line naming file, line and column, results and truths rebuilt into
a model that predicts what the written one did."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io.serial_io import (load_robot, load_serial_result, read_joint_table, read_serial_campaign,
                                     resolve_robot, serial_result_dict, serial_truth_dict, write_serial_campaign,
                                     write_serial_result)
from olti_drake.model.serial import DistanceMeasurement, build_position_model, synthetic_campaign, synthetic_truth

TOOL = (40.0, -25.0, 60.0)
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])


@pytest.fixture(scope="module")
def chain():
    return load_robot("ur5", "tool0")


@pytest.fixture(scope="module")
def truth(chain):
    return synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)


@pytest.fixture(scope="module")
def camp(truth):
    return synthetic_campaign(truth, 40, seed=4, ranges_deg=RANGES)


def test_shipped_robot_names_resolve_to_the_package_models(tmp_path):
    assert resolve_robot("ur5").name == "ur5.urdf" and resolve_robot("ur5").is_file()
    assert resolve_robot("SCARA").name == "scara.sdf" and resolve_robot("scara").is_file()
    assert resolve_robot("arm.urdf", tmp_path) == tmp_path / "arm.urdf"


def test_distance_and_point_campaigns_round_trip(tmp_path, camp):
    path = tmp_path / "d.csv"
    write_serial_campaign(path, camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    c = read_serial_campaign(path, 6)
    assert c.kind == "distance" and c.dirs is not None
    assert np.abs(c.commands - camp.distance_commands).max() < 1e-9
    assert np.abs(c.displacement_mm - camp.displacement_mm).max() < 1e-9
    assert np.array_equal(c.station, camp.station)
    with pytest.raises(ValueError, match="holds measured data"):  # a measurement is never replaced
        write_serial_campaign(path, camp.distance_commands, station=camp.station, displacement_mm=camp.displacement_mm)
    p = tmp_path / "p.csv"
    write_serial_campaign(p, camp.commands, None, points_mm=camp.points_mm, valid=np.r_[0, np.ones(39)])
    c = read_serial_campaign(p)
    assert c.kind == "point" and c.dirs is None and len(c) == 39 and c.n_skipped == 1
    assert np.abs(c.points_mm - camp.points_mm[1:]).max() < 1e-9
    # 'reflector' is the synonym of 'station'
    text = (tmp_path / "d.csv").read_text().replace("station,", "reflector,")
    (tmp_path / "r.csv").write_text(text)
    assert np.array_equal(read_serial_campaign(tmp_path / "r.csv", 6).station, camp.station)


def _campaign_text(n=6, rows=6, station=True, dirs=True):
    head = (["station"] if station else []) + [f"theta{i}_deg" for i in range(1, n + 1)]
    head += [f"dir{i}" for i in range(1, n + 1)] if dirs else []
    head += ["displacement_mm"]
    lines = [",".join(head)]
    for r in range(rows):
        vals = ([str(r % 1)] if station else []) + [f"{10 * r + i}" for i in range(n)]
        vals += ["1"] * n if dirs else []
        vals += [f"{100 + r}.5"]
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("edit, expect", [
    (lambda t: _campaign_text(n=5), ":1: 5 joint columns (theta1_deg .. theta5_deg) but the robot ur5 has 6"),
    (lambda t: t.replace("30,31,32", "30,nan,32"), ":5: column 'theta2_deg': nan is not finite"),
    (lambda t: t.replace(",displacement_mm", ",disp"), "missing required column 'displacement_mm'"),
    (lambda t: t.replace("1,1,1,1,1,1,103.5", "1,1,1,1,1,0,103.5"), ":5: column 'dir6': 0 is not one of -1, 1"),
    (lambda t: t.replace(",dir6", ",dirx"), ":1: missing column 'dir6': direction columns dir1 .. dir6 come all"),
    (lambda t: _campaign_text(rows=4), "station 0 has 4 valid reading(s) (first on line 2); a station needs at least 5"),
    (lambda t: t.replace("theta3_deg", "theta9_deg"), "column 'theta4_deg' without 'theta3_deg'"),
    (lambda t: t + t.splitlines()[3] + "\n", ":8: row identical in every column to line 4"),
    (lambda t: t.replace("102.5", "1e9"), ":4: column 'displacement_mm': 1e+09 is beyond +-100000 mm"),
])
def test_malformed_campaigns_are_one_line_naming_the_place(tmp_path, edit, expect):
    path = tmp_path / "c.csv"
    path.write_text(edit(_campaign_text()))
    with pytest.raises(InputError) as e:
        read_serial_campaign(path, 6, robot="ur5")
    assert expect in str(e.value) and "\n" not in str(e.value)
    assert str(e.value).startswith(str(path))


def test_targets_table_keeps_optional_dirs(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("x_mm,y_mm,z_mm,theta1_deg,theta2_deg\n1,2,3,10,20\n4,5,6,11,21\n")
    jt = read_joint_table(path, 2, ("x_mm", "y_mm", "z_mm"))
    assert jt.dirs is None and jt.commands.shape == (2, 2) and list(jt.line) == [2, 3]


def test_result_written_and_loaded_predicts_the_same_points(tmp_path, chain, camp):
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=30.0,
                                 tool_offset_mm=TOOL)
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station, camp.displacement_mm,
                               np.ones((4, 3)) * 900, np.arange(4.0))
    rng = np.random.default_rng(1)
    x = meas.start_vector() + 0.01 * rng.normal(size=len(meas.names))
    fit = types.SimpleNamespace(x=x, std=np.full(len(x), 1e-3), residuals=np.zeros(7), iterations=3,
                                condition_number=10.0, solver="lm", outliers=[], converged_by="test", warnings=[],
                                notes=[])
    res = serial_result_dict(kind="errormap", robot_file="ur5", measurement=meas, fit=fit, gauge="g")
    assert set(res["error_map"]) == set(chain.joint_names) and res["robot"]["joints"] == list(chain.joint_names)
    assert "reverse_deg" in res["uncertainty"]["error_map"]["shoulder_pan_joint"]
    write_serial_result(tmp_path / "r.json", res)
    back = load_serial_result(tmp_path / "r.json")
    xm = x[:model.n_params]
    assert np.abs(back.model.positions(camp.commands, camp.dirs)
                  - model.positions(camp.commands, camp.dirs, xm)).max() < 1e-9
    assert np.abs(back.stations_mm - x[model.n_params:model.n_params + 12].reshape(4, 3)).max() == 0
    # a result naming a robot file relative to itself, and one whose joints disagree
    res["robot"]["file"] = "missing.urdf"
    (tmp_path / "bad.json").write_text(json.dumps(res))
    with pytest.raises(InputError, match="robot.file: robot model .*missing.urdf: file not found"):
        load_serial_result(tmp_path / "bad.json")


def test_truth_with_fine_maps_loads_as_a_model(tmp_path, chain, truth, camp):
    (tmp_path / "truth.json").write_text(json.dumps(serial_truth_dict(truth, "ur5", grid_step_deg=0.05,
                                                                      ranges_deg=RANGES)))
    back = load_serial_result(tmp_path / "truth.json")
    err = np.linalg.norm(back.model.positions(camp.commands, camp.dirs) - truth.positions(camp.commands, camp.dirs),
                         axis=1)
    assert err.max() < 1e-3  # 0.05 deg nodes: interpolation of the harmonics well below a micrometre
    with pytest.raises(InputError, match="a simulation truth"):
        load_serial_result(tmp_path / "truth.json", identified=True)


def test_compensation_refuses_a_command_beyond_the_joint_limits():
    """The model's joint limits are respected where the tool proposes commands: a target whose command lies
    beyond j1's limit (3 rad = 171.9 deg) is refused naming the line, the joint and the limit."""
    from pathlib import Path

    from olti_drake.estimation.serial_compensation import compensate_serial

    chain = load_robot(Path(__file__).resolve().parents[1] / "data" / "missing_mesh.urdf", "tool")
    model = build_position_model(chain, np.array([[0.0, 0.0], [10.0, 20.0], [-30.0, 5.0]]), kind="dh",
                                 tool_offset_mm=(10.0, 5.0, 0.0))
    nominal = np.array([[160.0, 10.0], [168.0, 10.0]])
    inside = compensate_serial(model, model.positions(nominal), nominal, source="t.csv")
    assert inside.residual_mm.max() < 1e-6 and np.abs(inside.correction_deg).max() < 1e-6
    target = model.positions(np.array([[160.0, 10.0], [175.0, 10.0]]))
    with pytest.raises(InputError, match=r"t.csv:3: the compensated command of j1 is 175 deg, beyond its limit "
                                         r"171.887 deg"):
        compensate_serial(model, target, nominal, lines=[2, 3], source="t.csv")
