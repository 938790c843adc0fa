"""Compensation (000 Eq. 3 with Eq. 7 inverted) and its proof on the simulated robot; mm and degrees."""

import csv
import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from olti_drake.estimation import compensation as comp
from olti_drake.report import validation as v
from olti_drake.sim.campaign import prepare, simulate_vectorized
from olti_drake.sim.compensation_check import drake_end_effector
from olti_drake.model.errormap import ErrorMap, approach_directions
from olti_drake.estimation.identification import IdentificationOptions, identify
from olti_drake.model.scara import ScaraModel, inverse_kinematics
from olti_drake.io.result import write_result
from olti_drake.model.scara import TrueRobot
from olti_drake.sim.scenario import Scenario
from olti_calls import error_line, olti_sub

ROOT = Path(__file__).resolve().parents[2]
COMBOS = np.array(comp.DIRECTION_COMBOS, dtype=float)


def _identify(noise: bool, seed: int = 0):
    scenario = Scenario()
    scenario.interferometer.noise = noise
    scenario.interferometer.quantization = noise
    setup = prepare(scenario)
    data = v.campaign_data(simulate_vectorized(setup, np.random.default_rng(seed)))
    return setup, identify(data, IdentificationOptions(model="errormap"))


@pytest.fixture(scope="module")
def noisy():
    """The paper set-up: continuous truth with backlash, campaign with the Table 2 noise, error map identified."""
    return _identify(noise=True, seed=3)


@pytest.fixture(scope="module")
def exact():
    """A noise-free identified model and a truth robot that *is* that model (truth == model)."""
    _, ident = _identify(noise=False)
    m = ident.model
    truth = TrueRobot(m.L1_mm, m.L2_mm, {"J1": m.map1, "J2": m.map2})
    return ident, truth


def _unseen_targets(model, seed=0):
    """Grid paths (derived directions) and random targets with given random directions, inside the map range."""
    g1, g2 = model.map1.grid_deg, model.map2.grid_deg
    r1, r2 = (g1[0] + 1, g1[-1] - 1), (2.0, g2[-1] - 1)
    return v.grid_paths(325.0, 225.0, r1, r2), v.random_commands(300, seed, r1, r2)


def _write_targets(path, rows, header="x_mm,y_mm"):
    path.write_text("# targets for olti compensate\n" + header + "\n" + "".join(",".join(map(str, r)) + "\n"
                                                                               for r in rows))
    return path


# -- (a) truth == model: the commands hit the targets exactly, in every direction combination ------------
def test_truth_equal_model_hits_targets_in_all_direction_combos(exact):
    ident, truth = exact
    m = ident.model
    assert np.max(np.abs(m.map1.forward_deg - m.map1.reverse_deg)) > 5e-3  # backlash: forward != reverse
    assert np.max(np.abs(m.map2.forward_deg - m.map2.reverse_deg)) > 5e-3
    assert abs(comp.frame_rotation_deg(truth)) < 1e-9  # the model's gauge: no rotation about J1
    grid, rnd = _unseen_targets(m)
    xy = np.vstack([grid.xy_cmd_mm, rnd.xy_cmd_mm])
    for d1, d2 in COMBOS:
        c = comp.compensate(m, xy[:, 0], xy[:, 1], np.full(len(xy), d1), np.full(len(xy), d2))
        e = comp.positioning_errors(truth, c.commands, xy)
        assert np.max(np.hypot(*e.T)) < 1e-6
        assert c.residual_mm.max() <= comp.TOLERANCE_MM and c.iterations <= 5
        # The direction is part of the command: executed the other way, the same commands miss by µm.
        flipped = dataclasses.replace(c.commands, dir1=-c.commands.dir1, dir2=-c.commands.dir2)
        assert np.median(np.hypot(*comp.positioning_errors(truth, flipped, xy).T)) > 1e-3


def test_derived_directions_are_a_fixed_point_and_drake_agrees(exact):
    ident, truth = exact
    grid, _ = _unseen_targets(ident.model)
    c = comp.compensate(ident.model, grid.xy_cmd_mm[:, 0], grid.xy_cmd_mm[:, 1])
    cmd = c.commands
    derived = approach_directions(np.column_stack([cmd.theta1_deg, cmd.theta2_deg]))
    np.testing.assert_array_equal(derived, np.column_stack([cmd.dir1, cmd.dir2]))
    assert not c.needs_approach.any()
    assert np.max(np.hypot(*comp.positioning_errors(truth, cmd, grid.xy_cmd_mm).T)) < 1e-6
    # The Drake diagram (ErrorMapJoint + MultibodyPlant) derives the directions from the sequence itself.
    p, d = drake_end_effector(truth, cmd)
    np.testing.assert_array_equal(d, derived)
    np.testing.assert_allclose(p, grid.xy_cmd_mm, rtol=0, atol=1e-6)


def test_reversal_within_backlash_is_flagged():
    b = 0.02  # backlash, deg: forward +0.01, reverse -0.01
    m = ErrorMap([-180.0, 180.0], [0.01, 0.01], [-0.01, -0.01], axis="J1")
    wanted = np.array([10.0, 20.0, 19.995, 15.0, 15.0, 14.99, 15.5, 15.51])
    plus, _ = comp.invert_axis(m, wanted, 1.0)
    minus, _ = comp.invert_axis(m, wanted, -1.0)
    dirs, flag = comp.sequence_directions(plus, minus)
    # 20 -> 19.995 reverses by 5 mdeg < b: no direction is confirmed by its own step; the reversal is kept.
    assert flag.tolist() == [False, False, True, False, False, False, False, False]
    assert dirs.tolist() == [1, 1, -1, -1, -1, -1, 1, 1]
    cmd = np.where(dirs > 0, plus, minus)
    np.testing.assert_allclose(cmd + m(cmd, dirs), wanted, rtol=0, atol=1e-12)
    seq = approach_directions(cmd)
    assert seq[2] == 1  # executed literally the flagged target would be approached +1: it needs an overrun move
    np.testing.assert_array_equal(seq[~flag], dirs[~flag])
    assert b > abs(wanted[2] - wanted[1])


def test_dh_model_compensates_theta20():
    m = ScaraModel(324.9, 225.1, 0.02)
    x, y = np.array([300.0, 0.0, -200.0]), np.array([100.0, 400.0, -350.0])
    c = comp.compensate(m, x, y)
    t1, t2 = inverse_kinematics(x, y, 324.9, 225.1)
    np.testing.assert_allclose(c.commands.theta1_deg, t1, atol=1e-12)
    np.testing.assert_allclose(c.commands.theta2_deg, t2 - 0.02, atol=1e-12)
    assert c.residual_mm.max() < 1e-9


# -- (b) the paper's continuous truth: compensation improves positioning >= 5x on unseen targets ----------
def test_paper_truth_improvement_on_unseen_targets(noisy):
    setup, ident = noisy
    nominal = ScaraModel(325.0, 225.0, 0.0)
    grid, rnd = _unseen_targets(ident.model, seed=11)
    for xy, dirs in ((grid.xy_cmd_mm, (None, None)), (rnd.xy_cmd_mm, (rnd.commands.dir1, rnd.commands.dir2))):
        res = comp.compare_compensation({"before": nominal, "after": ident.model}, setup.robot, xy, *dirs)
        before, after = res["before"], res["after"]
        assert before["rms_mm"] / after["rms_mm"] >= 5.0, (before["rms_mm"], after["rms_mm"])
        assert before["rms_registered_mm"] / after["rms_registered_mm"] >= 5.0
        assert after["max_mm"] < before["max_mm"] / 3
        for d1, d2 in comp.DIRECTION_COMBOS:  # every approach combination improves
            key = f"rms_{d1:+d}{d2:+d}_mm"
            if after[f"n_{d1:+d}{d2:+d}"] >= 10:
                assert after[key] < before[key] / 3, key


# -- (d) tables -----------------------------------------------------------------------------------------------
def test_tables_invert_the_map(exact):
    m = exact[0].model
    for mp in (m.map1, m.map2):
        t = comp.compensation_table(mp)
        clamp = dataclasses.replace(mp, outside="clamp")
        for key, d in (("forward_command_deg", 1.0), ("reverse_command_deg", -1.0)):
            np.testing.assert_allclose(t[key] + clamp(t[key], d), t["angle_deg"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(t["forward_correction_deg"], t["forward_command_deg"] - mp.grid_deg, atol=0)
        assert np.max(np.abs(t["forward_correction_deg"] - t["reverse_correction_deg"])) > 5e-3  # backlash


# -- CLI: (c) unreachable targets, (e) end to end, tables, missing columns, no overwrite -------------------------
@pytest.fixture(scope="module")
def result_json(tmp_path_factory, noisy):
    path = tmp_path_factory.mktemp("result") / "result.json"
    write_result(noisy[1], path)
    return path


def test_cli_rejects_unreachable_targets_with_line(tmp_path, result_json):
    t = _write_targets(tmp_path / "targets.csv", [(300, 100), (200, -300), (900, 0)])
    r = olti_sub("compensate", result_json, t, "--out", tmp_path / "c.csv")
    error_line(r.returncode, r.stderr)
    assert r.stderr.startswith(f"error: {t}:5: ") and "reach" in r.stderr
    # Reachable, but the commands leave the identified J1 map [-140, 60] deg: refused, no extrapolation.
    t = _write_targets(tmp_path / "targets2.csv", [(300, 100), (-300, 300)])
    r = olti_sub("compensate", result_json, t, "--out", tmp_path / "c.csv")
    assert r.returncode == 2 and f"{t}:4: " in r.stderr and "J1" in r.stderr and "grid" in r.stderr
    assert not (tmp_path / "c.csv").exists()


def test_cli_end_to_end_predict_maps_back_to_targets(tmp_path, result_json, noisy):
    grid, rnd = _unseen_targets(noisy[1].model, seed=5)
    targets = _write_targets(tmp_path / "targets.csv", grid.xy_cmd_mm[:60])
    out, pred = tmp_path / "commands.csv", tmp_path / "pred.csv"
    r = olti_sub("compensate", result_json, targets, "--out", out, "--tables", tmp_path / "tables")
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and "Newton" in r.stdout
    r = olti_sub("predict", result_json, out, "--out", pred)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(line for line in pred.read_text().splitlines() if not line.startswith("#")))
    xy = np.array([[float(row["x_mm"]), float(row["y_mm"])] for row in rows])
    np.testing.assert_allclose(xy, grid.xy_cmd_mm[:60], rtol=0, atol=2e-6)
    q = np.array([[float(row[k]) for k in ("theta1_deg", "theta2_deg", "dir1", "dir2")] for row in rows])
    np.testing.assert_array_equal(approach_directions(q[:, :2]), q[:, 2:])  # derived: the sequence's own
    # The tables, read back: the corrected command through the map gives the wanted angle.
    model = noisy[1].model
    for mp in (model.map1, model.map2):
        path = tmp_path / "tables" / f"{mp.axis}_compensation.csv"
        rows = list(csv.DictReader(line for line in path.read_text().splitlines() if not line.startswith("#")))
        tab = {k: np.array([float(row[k]) for row in rows]) for k in rows[0]}
        clamp = dataclasses.replace(mp, outside="clamp")
        for key, d in (("forward_command_deg", 1.0), ("reverse_command_deg", -1.0)):
            np.testing.assert_allclose(tab[key] + clamp(tab[key], d), tab["angle_deg"], rtol=0, atol=1e-9)


def test_cli_given_directions_are_kept(tmp_path, result_json, noisy):
    _, rnd = _unseen_targets(noisy[1].model, seed=6)
    rows = [(x, y, int(a), int(b)) for (x, y), a, b in zip(rnd.xy_cmd_mm[:40], rnd.commands.dir1[:40],
                                                           rnd.commands.dir2[:40])]
    targets = _write_targets(tmp_path / "t.csv", rows, header="x_mm,y_mm,dir1,dir2")
    r = olti_sub("compensate", result_json, targets, "--out", tmp_path / "c.csv")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in (tmp_path / "c.csv").read_text().splitlines() if not ln.startswith("#")]
    got = list(csv.DictReader(lines))
    assert [(int(g["dir1"]), int(g["dir2"])) for g in got] == [(a, b) for _, _, a, b in rows]


def test_cli_bad_inputs(tmp_path, result_json):
    t = _write_targets(tmp_path / "t.csv", [(300,), (200,)], header="x_mm")
    r = olti_sub("compensate", result_json, t, "--out", tmp_path / "c.csv")
    error_line(r.returncode, r.stderr, "'y_mm'")
    t = _write_targets(tmp_path / "t2.csv", [(300, 100, 1), (200, 100, 0)], header="x_mm,y_mm,dir1")
    r = olti_sub("compensate", result_json, t, "--out", tmp_path / "c.csv")
    assert r.returncode == 2 and f"{t}:4: column 'dir1'" in r.stderr
    t = _write_targets(tmp_path / "t3.csv", [(300, 100)])
    before = t.read_text()
    r = olti_sub("compensate", result_json, t, "--out", t)
    assert r.returncode == 2 and "overwrite" in r.stderr and t.read_text() == before


def test_example_runs_and_reports_improvement(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "compensate_paper.py"), "--out", str(tmp_path)],
                       capture_output=True, text=True, cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "compensation_before_after.png").stat().st_size > 10_000
    assert "directions derived by ErrorMapJoint equal" in r.stdout
    ratios = [float(s.split()[-1].rstrip("x")) for s in r.stdout.split("RMS improvement before/after:")[1]
              .splitlines()[0].split(";")]
    assert len(ratios) == 3 and min(ratios) >= 5.0


def test_example_figure_shows_the_errors_before_and_after(tmp_path):
    """examples/compensate_paper.py's figure: tips at target + 1000 x error, RMS and max in the titles."""
    import importlib.util

    from figure_capture import captured_figures, legend_labels, line, lines_with, points, same_points

    spec = importlib.util.spec_from_file_location("compensate_paper", ROOT / "examples" / "compensate_paper.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    rng = np.random.default_rng(5)
    targets = rng.uniform(200, 400, (20, 2))
    dir1 = np.where(np.arange(20) % 2 == 0, 1, -1)
    before, after = rng.normal(0, 0.1, (20, 2)), rng.normal(0, 0.01, (20, 2))
    with captured_figures() as figs:
        example.plot_before_after(targets, (before, dir1), (after, dir1), tmp_path / "ba.png")
    for ax, e, what in zip(figs["ba.png"].axes, (before, after), ("before", "after")):
        rms, worst = 1e3 * np.sqrt(np.mean(np.sum(e ** 2, axis=1))), 1e3 * np.max(np.hypot(*e.T))
        assert ax.get_title().startswith(what) and f"RMS {rms:.1f} µm, max {worst:.1f} µm" in ax.get_title()
        tips = points(lines_with(ax, marker="o"))
        assert same_points(tips, targets + 1000.0 * e, atol=1e-9)
        np.testing.assert_allclose(line(ax, "targets"), targets)
    assert legend_labels(figs["ba.png"].axes[0]) == ["J1 approach +1", "J1 approach -1", "targets"]
