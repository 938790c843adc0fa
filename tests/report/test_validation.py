"""Validation on unseen paths (000 §4.3, Figs. 9-11): registration, command sets, models, figures, demo.

Units: mm and degrees; errors compared in mm, printed in µm.
"""

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from figure_capture import (annotations, captured_figures, errorbar, legend_labels, line, lines_with, points,
                            same_points, suptitle)
from olti_calls import olti_sub

from olti_drake.report import validation as v
from olti_drake.sim.campaign import prepare, run_campaign, write_campaign
from olti_drake.io.csvio import load_campaign
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM, JointCommands, ScaraModel, forward_kinematics
from olti_drake.sim.scenario import Scenario
from olti_drake.sim.tracker import LaserTrackerSpec

FIGURES = ("fig5_poses_reflectors.png", "fig6_truth_maps.png", "fig6_maps.png", "fig9_10_x200.png",
           "fig11_error_vectors.png")


@pytest.fixture(scope="module")
def paper():
    """The simulated paper campaign (continuous truth, default scenario) and its validation report."""
    setup = prepare(Scenario())
    campaign = run_campaign(setup)
    report = v.validate_models(v.campaign_data(campaign), setup.robot, seed=setup.scenario.seed)
    return setup, campaign, report


def rotate(p, angle_deg):
    a = np.radians(angle_deg)
    return p @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])


def test_register_recovers_a_known_rotation_exactly():
    p = np.random.default_rng(1).uniform(-500, 500, (50, 2))
    for angle in (0.0123, -7.5, 170.0):
        rotated, found = v.register(p, rotate(p, angle))
        assert found == pytest.approx(angle, abs=1e-12)
        np.testing.assert_allclose(rotated, rotate(p, angle), atol=1e-10)


def test_compare_is_zero_for_a_rotated_copy_and_splits_by_direction():
    cmd = v.random_commands(40, 3).commands
    model = ScaraModel()
    meas = rotate(model.positions(cmd), 0.02)
    meas[cmd.dir1 < 0] += [0.003, -0.004]  # 5 µm on the reverse rows only: no rotation removes it
    c = v.compare({"m": model}, cmd, meas)["m"]
    assert c["errors"].shape == (40, 2)
    assert c["rms_fwd_mm"] < c["rms_rev_mm"]
    exact = v.compare({"m": model}, cmd, rotate(model.positions(cmd), 0.02))["m"]
    assert exact["rms_mm"] < 1e-10 and exact["rotation_deg"] == pytest.approx(0.02, abs=1e-12)


def test_x200_path_commands_reproduce_x200_through_nominal_kinematics():
    s = v.x200_path()
    p = forward_kinematics(s.commands.theta1_deg, s.commands.theta2_deg, PAPER_L1_MM, PAPER_L2_MM)[0]
    np.testing.assert_allclose(p[:, 0], 200.0, atol=1e-9)
    np.testing.assert_allclose(p, s.xy_cmd_mm, atol=1e-9)
    y = np.arange(-500.0, 500.1, 25.0)
    np.testing.assert_allclose(p[:, 1], np.concatenate([y, y[::-1]]), atol=1e-9)  # forward, then back
    np.testing.assert_array_equal(s.pass_dir, np.repeat([1.0, -1.0], y.size))
    # Directions are per axis: on the forward pass the elbow J2 opens up to Y = 0, then closes.
    np.testing.assert_array_equal(s.commands.dir2[:y.size], np.where(y <= 0, 1.0, -1.0))


def test_grid_paths_and_random_commands_stay_in_the_map_range():
    g = v.grid_paths(theta1_range=(-140, 60), theta2_range=(0, 140))
    r = v.random_commands(500, 7)
    for s in (g, r):
        c = s.commands
        assert c.theta1_deg.min() >= -140 - 1e-9 and c.theta1_deg.max() <= 60 + 1e-9
        assert c.theta2_deg.min() >= -1e-9 and c.theta2_deg.max() <= 140 + 1e-9
        np.testing.assert_allclose(forward_kinematics(c.theta1_deg, c.theta2_deg, PAPER_L1_MM, PAPER_L2_MM)[0],
                                   s.xy_cmd_mm, atol=1e-9)
    # Straight paths: each path's points share X or Y; X-paths and Y-paths both present.
    kinds = set()
    for i in np.unique(g.path_id):
        xy = g.xy_cmd_mm[g.path_id == i]
        kinds.add("Y-path" if np.ptp(xy[:, 0]) == 0 else "X-path" if np.ptp(xy[:, 1]) == 0 else "bent")
    assert kinds == {"X-path", "Y-path"}
    # Random: seeded, both directions on both axes.
    np.testing.assert_array_equal(v.random_commands(500, 7).commands.theta1_deg, r.commands.theta1_deg)
    assert set(r.commands.dir1) == {-1.0, 1.0} and set(r.commands.dir2) == {-1.0, 1.0}


def test_measure_is_truth_plus_seeded_tracker_noise(paper):
    setup, _, _ = paper
    c = v.random_commands(200, 5).commands
    truth = setup.robot.end_effector(c.theta1_deg, c.theta2_deg, c.dir1, c.dir2)
    exact = LaserTrackerSpec(u_const_um=0.0, u_per_m_um=0.0)
    np.testing.assert_array_equal(v.measure(setup.robot, c, exact, seed=0), truth)
    a, b = v.measure(setup.robot, c, seed=3), v.measure(setup.robot, c, seed=3)
    np.testing.assert_array_equal(a, b)
    noise = np.std(a - truth)
    assert 0.004 < noise < 0.010, noise  # AT960-XR: 15 µm + 6 µm/m at k = 2, per coordinate / sqrt(3)


def test_campaign_data_equals_the_written_and_loaded_campaign(paper, tmp_path):
    _, campaign, _ = paper
    data = v.campaign_data(campaign)
    loaded = load_campaign(write_campaign(campaign, tmp_path)[0])
    assert data.n_skipped == loaded.n_skipped == 1
    np.testing.assert_array_equal(data.reflector, loaded.reflector)
    np.testing.assert_allclose(data.displacement_mm, loaded.displacement_mm, atol=1e-9)
    for f in ("theta1_deg", "theta2_deg", "dir1", "dir2"):
        np.testing.assert_allclose(getattr(data.commands, f), getattr(loaded.commands, f), atol=1e-9)


def test_error_map_predicts_unseen_random_commands_5x_better_than_dh(paper):
    _, _, report = paper
    r = report.results["random"]
    assert len(r.commands) == 500 and r.n_outside_map == 0
    dh, em = r.comparison["D-H"]["rms_mm"], r.comparison["error map"]["rms_mm"]
    print(f"\n500 random unseen commands: D-H RMS {1e3 * dh:.1f} um, error map RMS {1e3 * em:.1f} um")
    assert dh >= 5 * em
    # The error map's rotation is the gauge: the truth's J1 level at 0 deg (12.2 mdeg), within 2 mdeg.
    assert r.comparison["error map"]["rotation_deg"] == pytest.approx(0.0122, abs=0.002)


def test_x200_path_beyond_the_map_is_predicted_with_held_ends(paper):
    _, _, report = paper
    r = report.results["x200"]
    assert r.n_outside_map == 10  # |Y| < 65 mm needs theta2* > 140 deg with the paper robot
    assert r.comparison["error map"]["max_mm"] < 0.06
    assert r.comparison["D-H"]["rms_mm"] > 4 * r.comparison["error map"]["rms_mm"]


def test_validation_figures_are_written(paper, tmp_path):
    setup, _, report = paper
    with captured_figures() as figs:
        paths = v.write_validation_figures(report, tmp_path, setup)
    assert [os.path.basename(p) for p in paths] == list(FIGURES[2:]) == list(figs)
    for p in paths:
        with open(p, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_fig6_shows_the_identified_maps_with_their_error_bars_and_the_gauge_shifted_truth(paper, tmp_path):
    setup, _, report = paper
    ident = report.identifications["error map"]
    with captured_figures() as figs:
        v.write_validation_figures(report, tmp_path, setup)
    axes = figs["fig6_maps.png"].axes
    std = dict(zip(ident.names, ident.std))
    for ax, axis, m in ((axes[0], "J1", ident.model.map1), (axes[1], "J2", ident.model.map2)):
        assert ax.get_xlabel() == f"{axis} command angle θ{axis[1]}*, deg"
        assert ax.get_ylabel() == "angular positioning deviation, mdeg"
        for (d, name), values, block in (((1, "positive (+1)"), m.forward_deg, "forward"),
                                         ((-1, "negative (-1)"), m.reverse_deg, "reverse")):
            label = f"identified, {name}, error bar u (k = 1)"
            assert label in legend_labels(ax)
            x, y, half = errorbar(ax, label)
            np.testing.assert_allclose(x, m.grid_deg)
            np.testing.assert_allclose(y, 1e3 * values)
            u = [std[f"{axis}_{block}_deg[{i}]"] for i in range(m.n_nodes)]
            np.testing.assert_allclose(half, 1e3 * np.array(u), rtol=1e-9)  # the bar is u (k = 1), mdeg
            truth = [lab for lab in legend_labels(ax) if lab.startswith(f"truth, {name}")]
            assert len(truth) == 1
        shift = 1e3 * np.mean(setup.robot.deviation("J1")(np.array([0.0, 0.0]), np.array([1.0, -1.0])))
        truth_line = [ln for ln in ax.get_lines() if ln.get_label().startswith("truth, positive")][0]
        x = truth_line.get_xdata()
        expected = 1e3 * setup.robot.deviation(axis)(x, 1) - (shift if axis == "J1" else 0.0)
        np.testing.assert_allclose(truth_line.get_ydata(), expected, atol=1e-9)
    assert f"- {shift:.2f} mdeg (gauge: mean at 0 deg = 0)" in "".join(legend_labels(axes[0]))


def test_figs_9_10_plot_the_measured_and_predicted_deviations_along_x200(paper, tmp_path):
    setup, _, report = paper
    r = report.results["x200"]
    cmd, meas = r.commands.xy_cmd_mm, r.measured_mm
    dh, em = r.comparison["D-H"]["predicted_mm"], r.comparison["error map"]["predicted_mm"]
    with captured_figures() as figs:
        v.write_validation_figures(report, tmp_path, setup)
    axes = np.array(figs["fig9_10_x200.png"].axes).reshape(2, 2)
    for col, c, name in ((0, 1, "E_YY = y - y*"), (1, 0, "E_XY = x - x*")):
        assert axes[0, col].get_ylabel() == axes[1, col].get_ylabel() == f"{name}, µm"
        assert axes[1, col].get_xlabel() == "command Y, mm (X = 200 mm)"
        np.testing.assert_allclose(line(axes[0, col], "D-H model"),
                                   np.column_stack([cmd[:, 1], 1e3 * (dh - cmd)[:, c]]))
        for d, dname in ((1, "forward pass (+1)"), (-1, "return pass (-1)")):
            s = r.commands.pass_dir == d
            measured = np.column_stack([cmd[s, 1], 1e3 * (meas - cmd)[s, c]])
            for row in (0, 1):
                np.testing.assert_allclose(line(axes[row, col], f"measured, {dname}"), measured)
            np.testing.assert_allclose(line(axes[1, col], f"error-map model, {dname}"),
                                       np.column_stack([cmd[s, 1], 1e3 * (em - cmd)[s, c]]))
        assert "D-H model" not in legend_labels(axes[1, col])


def test_fig11_says_which_rms_is_a_prediction_and_which_an_accuracy(paper, tmp_path):
    setup, _, report = paper
    g = report.results["grid"]
    cmd, meas = g.commands.xy_cmd_mm, g.measured_mm
    em, dh = g.comparison["error map"]["predicted_mm"], g.comparison["D-H"]["predicted_mm"]
    with captured_figures() as figs:
        v.write_validation_figures(report, tmp_path, setup)
    fig = figs["fig11_error_vectors.png"]
    assert "not used in the identification" in suptitle(fig)

    def rms(e):
        return 1e3 * np.sqrt(np.mean(np.sum(e ** 2, axis=1)))

    expected = (("a) measured (tracker)", "RMS of the measured error", meas - cmd),
                ("b) error-map model", "RMS of the predicted deviation (not an accuracy)", em - cmd),
                ("c) D-H model", "RMS of the predicted deviation (not an accuracy)", dh - cmd),
                ("d) measured - error-map model", "RMS of the model's prediction error", meas - em))
    for ax, (title, what, err) in zip(fig.axes, expected):
        assert ax.get_title() == f"{title}\n{what}: {rms(err):.1f} µm"
        # The magnified tips (joined per path and pass) are the command plus 1000 x the error.
        tips = points(lines_with(ax, marker="o", linestyle="-"))
        assert same_points(tips, cmd + 1000.0 * err, atol=1e-6)
        assert same_points(line(ax, "command positions"), cmd)
    assert sorted(legend_labels(fig.axes[0])) == sorted(["forward pass (+1)", "return pass (-1)", "command positions"])
    assert any("error scale: 200 µm (x1000)" == t for t in annotations(fig.axes[0]))
    # The accuracy (d) of the error map is far better than the deviation it predicts (b).
    assert rms(meas - em) < 0.5 * rms(em - cmd)


def test_demo_prints_the_comparison_and_writes_everything(paper, tmp_path):
    _, _, report = paper
    r = olti_sub("demo", "--out", tmp_path, timeout=60, expect=0)
    row = re.search(r"\(c\) 500 random commands\s+500\s+([\d.]+) /\s+[\d.]+\s+([\d.]+) /", r.stdout)
    assert row, r.stdout
    dh, em = map(float, row.groups())
    # Deterministic: the demo's numbers are the in-process ones.
    assert dh == pytest.approx(1e3 * report.results["random"].comparison["D-H"]["rms_mm"], abs=0.051)
    assert em == pytest.approx(1e3 * report.results["random"].comparison["error map"]["rms_mm"], abs=0.051)
    assert "model dh:" in r.stdout and "model errormap:" in r.stdout
    for name in FIGURES + ("result_dh.json", "result_errormap.json", "campaign.csv", "truth.json"):
        assert (tmp_path / name).stat().st_size > 1000, name


def test_clamped_model_differs_only_outside_the_grid(paper):
    _, _, report = paper
    model = report.identifications["error map"].model
    inside = v.random_commands(50, 11).commands
    np.testing.assert_array_equal(v.holding_map_ends(model).positions(inside), model.positions(inside))
    outside = JointCommands([0.0], [150.0], [1.0], [1.0])
    assert v.outside_map(model, outside).all() and not v.outside_map(model, inside).any()
    assert np.all(np.isfinite(v.holding_map_ends(model).positions(outside)))


def test_example_script_validates_a_simulated_campaign_file(tmp_path):
    """examples/validate_paper_models.py on the files of `olti simulate`, with figures."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    olti_sub("simulate", "--out", tmp_path, timeout=60, expect=0)
    r = subprocess.run([sys.executable, os.path.join(root, "examples", "validate_paper_models.py"),
                        "--campaign", str(tmp_path / "campaign.csv"), "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "(c) 500 random commands" in r.stdout and "X = 350 mm path" in r.stdout
    for name in FIGURES[2:]:
        assert os.path.getsize(tmp_path / name) > 20_000, name
