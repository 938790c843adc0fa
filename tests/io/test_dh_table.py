"""The identified geometry as a D-H table (olti compensate --dh-out; issue 26, item 3): read back from the CSV, the
table's forward kinematics equals the identified geometric model (dh result of the UR5) to 1 um on 10^4 random poses
within the joint limits, the UR5's parallel axes (shoulder-elbow-wrist 1) named as Hayati rows; an error-map result's
table states what it cannot hold and a residual that a re-simulation reproduces."""

import os

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.io.dh_table import dh_positions, read_dh_table
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import load_serial_result
from olti_drake.io.ur_kinematics import _ranges
from olti_drake.model.chain import load_serial_chain
from olti_calls import error_line
from ur5_results import UR5, identified_ur5



@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return identified_ur5(tmp_path_factory.mktemp("dh"), 5, 200, 9, 3, "--dh-out", "_dh.csv")


def _poses(res, n=10_000, seed=1):
    rng = np.random.default_rng(seed)
    lo, hi = _ranges(res.model)
    return rng.uniform(lo, hi, (n, 6)), np.where(rng.random((n, 6)) < 0.5, -1.0, 1.0)


def test_a_geometric_result_round_trips_to_a_micrometre(results):
    res = load_serial_result(results / "dh.json")
    rows = read_dh_table(results / "dh_dh.csv")
    assert [r[0] for r in rows] == ["base"] + list(res.model.chain.joint_names)
    cmd, _ = _poses(res)
    d = np.linalg.norm(dh_positions(rows, cmd) - res.model.positions(cmd, None), axis=1)
    assert d.max() < 1e-3, d.max()
    nominal = load_serial_chain(UR5, "tool0").positions(cmd, res.model.chain.nominal_parameters((40, -25, 60)))
    assert np.linalg.norm(nominal - res.model.positions(cmd, None), axis=1).max() > 0.1  # (the table holds something)
    text = (results / "dh_dh.csv").read_text()
    # the UR5's shoulder, elbow and wrist 1 axes are parallel: Hayati rows, named by pair, with d = 0
    assert "shoulder_lift_joint-elbow_joint" in text and "elbow_joint-wrist_1_joint" in text
    by_name = {r[0]: r for r in rows}
    assert by_name["elbow_joint"][3] == 0.0 and abs(by_name["elbow_joint"][5]) < 1.0
    assert all(abs(r[3]) < 2000 for r in rows)  # (no common normal at infinity)


def test_an_error_map_result_states_the_residual_it_leaves(results):
    res = load_serial_result(results / "errormap.json", outside="clamp")
    text = (results / "errormap_dh.csv").read_text()
    assert "not held: the error maps'" in text and "not held: the tool frame's orientation" in text
    stated = float(text.split("RMS ")[1].split(" um")[0])
    rows = read_dh_table(results / "errormap_dh.csv")
    cmd, dirs = _poses(res, seed=0)  # (the writer's own poses: seed 0)
    d = np.linalg.norm(dh_positions(rows, cmd) - res.model.positions(cmd, dirs), axis=1)
    assert 1e3 * np.sqrt(np.mean(d ** 2)) == pytest.approx(stated, rel=0.01)
    assert stated > 0.1  # (the maps' shape is real: a table that claimed 0 would be wrong)


def test_a_result_of_another_kind_is_refused_in_one_line(tmp_path, capsys):
    """--dh-out applies to robots from a model file (cli/kinds.py OPTIONS): a SCARA result is refused before any
    work, in one line, nothing written."""
    root = os.path.dirname(PACKAGE_DIR)
    assert main(["identify", os.path.join(root, "data", "paper000", "campaign.csv"), "--model", "dh", "--out",
                 str(tmp_path / "scara.json")]) == 0
    capsys.readouterr()
    code = main(["compensate", str(tmp_path / "scara.json"), str(tmp_path / "none.csv"), "--out",
                 str(tmp_path / "c.csv"), "--dh-out", str(tmp_path / "dh.csv")])
    err = capsys.readouterr().err
    error_line(code, err)
    assert err.startswith("error: --dh-out (a D-H table) needs the result of a robot"), err
    assert not (tmp_path / "dh.csv").exists() and not (tmp_path / "c.csv").exists()
