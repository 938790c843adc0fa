"""The identified kinematics as a UR-style default_kinematics.yaml (olti compensate --ur-kinematics-out; issue 26,
item 3): read back by a YAML reader (Drake's) into a URDF of the robot with those joint origins, Drake's FK of it
at the identified tool point equals the identified geometric model to 1 um on 10^4 random poses; an error-map
result's file states what it cannot hold and the residual, which a re-simulation reproduces; a robot that is not
six joints or not a URDF is refused in one line before anything is written."""

import os

import numpy as np
import pytest

from olti_drake.io.serial_io import load_serial_result
from olti_drake.io.ur_kinematics import UR_SEGMENTS, tool_points, urdf_with_origins
from olti_drake.model.chain import load_serial_chain
from ur5_results import UR5, identified_ur5



@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return identified_ur5(tmp_path_factory.mktemp("urk"), 4, 250, 8, 5, "--ur-kinematics-out", "_kinematics.yaml")


def _read_back(path):
    from pydrake.common.yaml import yaml_load

    doc = yaml_load(filename=str(path))["kinematics"]
    segments = {s: tuple(float(doc[s][k]) for k in ("x", "y", "z", "roll", "pitch", "yaw")) for s in UR_SEGMENTS}
    return segments, doc["hash"]


def _file_points(tmp_path, segments, cmd, tool):
    chain = load_serial_chain(UR5, "tool0")
    path = tmp_path / "from_yaml.urdf"
    urdf_with_origins(UR5, segments, chain.joint_names, path)
    return tool_points(load_serial_chain(str(path), "tool0"), cmd, tool)


def _random(res, n=10_000, seed=1):
    rng = np.random.default_rng(seed)
    chain = res.model.chain
    lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -180.0)
    hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, 180.0)
    for m in res.model.maps:
        i = list(chain.joint_names).index(m.joint)
        lo[i], hi[i] = m.emap.grid_deg[0], m.emap.grid_deg[-1]
    return rng.uniform(lo, hi, (n, 6)), np.where(rng.random((n, 6)) < 0.5, -1.0, 1.0)


def test_a_geometric_result_round_trips_to_a_micrometre(results, tmp_path):
    res = load_serial_result(results / "dh.json")
    segments, hsh = _read_back(results / "dh_kinematics.yaml")
    assert hsh.startswith("calib_olti_")
    cmd, _ = _random(res)
    tool = res.model.chain_parameters(res.x)[-3:]
    d = np.linalg.norm(_file_points(tmp_path, segments, cmd, tool) - res.model.positions(cmd, None), axis=1)
    assert d.max() < 1e-3, d.max()
    nominal = tool_points(load_serial_chain(UR5, "tool0"), cmd, tool)
    assert np.linalg.norm(nominal - res.model.positions(cmd, None), axis=1).max() > 0.1  # (the file holds something)


def test_an_error_map_result_states_the_residual_it_leaves(results, tmp_path):
    res = load_serial_result(results / "errormap.json", outside="clamp")
    text = (results / "errormap_kinematics.yaml").read_text()
    assert "not held: the error maps'" in text and "not held: the tool point" in text
    stated = float(text.split("RMS ")[1].split(" um")[0])
    segments, _ = _read_back(results / "errormap_kinematics.yaml")
    cmd, dirs = _random(res, seed=0)  # (the writer's own poses: seed 0)
    tool = res.model.chain_parameters(res.x)[-3:]
    d = np.linalg.norm(_file_points(tmp_path, segments, cmd, tool) - res.model.positions(cmd, dirs), axis=1)
    assert 1e3 * np.sqrt(np.mean(d ** 2)) == pytest.approx(stated, rel=0.01)


def test_what_the_format_cannot_take_is_refused_before_writing(tmp_path, capsys):
    from olti_drake.io.ur_kinematics import ur_segments
    from olti_drake.errors import InputError

    chain = load_serial_chain(os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "seven_joint.urdf"), "tool0")
    from olti_drake.model.serial import build_position_model

    model = build_position_model(chain, chain.random_angles(20, seed=1), None, kind="dh")
    with pytest.raises(InputError, match="holds 6 joints, the robot has 7"):
        ur_segments(model, os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "seven_joint.urdf"))
