"""What the figures show (olti_drake.report.figures): labels, legends, annotations and the plotted data.

Each figure is caught as it is saved (tests/figure_capture.py) and read back: the reflectors are
P0, P1, ... as in the campaign file, every plotted point is the value it claims to be, and a title
or legend claims only what the figure shows. Units: mm, mdeg, µm.
"""

import dataclasses

import numpy as np
import pytest
from figure_capture import annotations, captured_figures, errorbar, legend_labels, line, suptitle

from olti_drake.report import figures
from olti_drake.sim.campaign import prepare, run_campaign
from olti_drake.model.scara import forward_kinematics
from olti_drake.sim.scenario import Scenario


@pytest.fixture(scope="module")
def small():
    """A short campaign (2 x 3 sweeps per reflector) with beam losses forced by a narrow acceptance."""
    s = Scenario()
    s.interferometer.acceptance_mm = 0.05  # open-loop aiming misses by more than this at some poses
    s.plan = dataclasses.replace(s.plan, theta1_start=-40.0, theta1_stop=0.0, theta2_start=40.0,
                                 theta2_stop=100.0, theta2_step=30.0)
    setup = prepare(s)
    return setup, run_campaign(setup)


def test_fig5_shows_every_command_and_the_reflectors_named_as_in_the_file(small, tmp_path):
    setup, campaign = small
    with captured_figures() as figs:
        paths = figures.write_campaign_figures(setup, campaign, tmp_path)
    assert sorted(figs) == sorted(p.split("/")[-1] for p in paths)
    ax = figs["fig5_poses_reflectors.png"].axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("X, mm", "Y, mm")
    c, r = campaign.columns, setup.scenario.robot
    p = forward_kinematics(c["theta1_deg"], c["theta2_deg"], r.nominal_L1_mm, r.nominal_L2_mm)[0]
    np.testing.assert_allclose(line(ax, "command positions p*(k)"), p)
    np.testing.assert_allclose(line(ax, "reflectors (true)"), setup.reflectors_mm)
    np.testing.assert_allclose(line(ax, "reflectors (estimate)"), setup.reflectors_estimate_mm)
    # P0..P2: the campaign's reflector index j (000 counts P_1..P_3).
    names = annotations(ax)
    assert sorted(names) == [f"P{j}" for j in range(len(setup.reflectors_mm))]
    for j, q in enumerate(setup.reflectors_mm):
        assert names[f"P{j}"] == pytest.approx(tuple(q))
    lost = c["valid"] < 0.5
    assert 0 < lost.sum() < lost.size
    np.testing.assert_allclose(line(ax, "beam lost"), p[lost])


def test_fig6_truth_maps_plot_the_simulated_deviation(small, tmp_path):
    setup, campaign = small
    with captured_figures() as figs:
        figures.write_campaign_figures(setup, campaign, tmp_path)
    axes = figs["fig6_truth_maps.png"].axes
    for ax, axis in zip(axes, ("J1", "J2")):
        assert ax.get_xlabel() == f"{axis} command angle, deg"
        assert legend_labels(ax) == ["truth, positive (+1)", "truth, negative (-1)"]
        for d, name in ((1, "positive (+1)"), (-1, "negative (-1)")):
            xy = line(ax, f"truth, {name}")
            np.testing.assert_allclose(xy[:, 1], 1e3 * getattr(setup.scenario.robot, axis)(xy[:, 0], d))


def _pmap():
    rng = np.random.default_rng(3)
    u = rng.uniform(1e-3, 5e-3, (2, 4, 5))
    u[:, 0, 0] = np.nan  # outside the map range
    return {"x_mm": np.linspace(-100, 300, 5), "y_mm": np.linspace(-200, 100, 4), "u_mm": u,
            "directions": (1.0, -1.0), "reflectors_mm": np.array([[650.0, -450.0], [600.0, 0.0], [650.0, 450.0]])}


def test_uncertainty_map_colours_are_k_times_u_and_the_reflectors_are_p0_p1_p2(tmp_path):
    pmap = _pmap()
    with captured_figures() as figs:
        figures.plot_prediction_uncertainty_map(pmap, tmp_path / "u.png", k=2.0, method="linear")
    fig = figs["u.png"]
    U = 2e3 * pmap["u_mm"]
    for i, ax in enumerate(fig.axes[:2]):
        mesh = ax.collections[0]
        np.testing.assert_allclose(np.ma.filled(mesh.get_array(), np.nan).ravel(), U[i].ravel())
        assert f"max {np.nanmax(U[i]):.1f} µm, mean {np.nanmean(U[i]):.1f} µm" in ax.get_title()
        assert sorted(annotations(ax)) == ["P0", "P1", "P2"]
        assert annotations(ax)["P2"] == (650.0, 450.0)
    assert fig.axes[2].get_ylabel().startswith("U (k = 2) of the predicted position")
    assert suptitle(fig).endswith("-- linear")


@pytest.mark.parametrize("with_references", [False, True])
def test_fig10_claims_the_digital_scale_only_when_it_draws_it(tmp_path, with_references):
    rng = np.random.default_rng(4)
    cmd = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
    est = cmd + rng.normal(0, 2e-3, cmd.shape)
    S = np.array([[-300.0, -200.0], [400.0, -200.0], [50.0, 500.0]])
    extra = dict(scale_mm=cmd + 1e-3, truth_mm=cmd + 2e-3) if with_references else {}
    with captured_figures() as figs:
        figures.plot_machine_targets(cmd, S, est, tmp_path / "f10.png", stations_label="stations (identified)",
                                     **extra)
    fig = figs["f10.png"]
    a, b = fig.axes
    np.testing.assert_allclose(line(a, "stations (identified)"), S)
    assert "stations (true table axis)" not in legend_labels(a)
    assert sorted(annotations(a)) == ["Pos A", "Pos B", "Pos C"]
    labels = legend_labels(b)
    assert ("vs the 2D digital scale" in suptitle(fig)) == with_references
    assert ("measured by the 2D digital scale" in labels) == with_references
    assert ("simulation truth" in labels) == with_references
    # The estimate drawn: the command plus 2000 x its error, around the closed loop of targets.
    tips = line(b, "estimated by the 'open-loop' tracking interferometer")
    loop = figures._perimeter_order(cmd)
    np.testing.assert_allclose(tips, (cmd + 2000.0 * (est - cmd))[loop])


def test_fig14_target_uncertainty_colours_each_target(tmp_path):
    cmd = np.array([[0.0, 0.0], [20.0, 0.0], [40.0, 0.0]])
    U = np.array([1.5, 2.5, 3.0])
    with captured_figures() as figs:
        figures.plot_target_uncertainty(cmd, U, tmp_path / "f14.png", k=2.0)
    ax = figs["f14.png"].axes[0]
    sc = ax.collections[0]
    np.testing.assert_allclose(sc.get_offsets(), cmd)
    np.testing.assert_allclose(sc.get_array(), U)
    assert "max 3.0 µm, mean 2.3 µm" in ax.get_title()
    assert [t.get_text() for t in ax.texts] == ["1.5", "2.5", "3.0"]


def test_fig13_linear_errors_plot_both_instruments_with_their_bars(tmp_path):
    x = np.array([0.0, 20.0, 40.0])
    panel = {"title": "X axis", "xlabel": "X, mm", "ylabel": "E_XX, µm", "position_mm": x,
             "estimate_um": np.array([0.0, 1.0, 2.5]), "expanded_um": np.array([0.5, 0.6, 0.7]),
             "laser_position_mm": x, "laser_um": np.array([0.1, 1.1, 2.4]), "laser_bound_um": np.array([0.2] * 3)}
    with captured_figures() as figs:
        figures.plot_linear_errors([panel, dict(panel, truth_um=np.array([0.05, 1.05, 2.45]))], tmp_path / "f13.png")
    a, b = figs["f13.png"].axes
    for ax in (a, b):
        assert (ax.get_title(), ax.get_xlabel(), ax.get_ylabel()) == ("X axis", "X, mm", "E_XX, µm")
        x_, y, half = errorbar(ax, "'open-loop' tracking interferometer, U (k = 2)")
        np.testing.assert_allclose(np.column_stack([x_, y, half]), np.column_stack([x, [0, 1, 2.5], [0.5, 0.6, 0.7]]))
        _, y, half = errorbar(ax, "linear laser interferometer (Table 1 ±)")
        np.testing.assert_allclose(y, [0.1, 1.1, 2.4])
        np.testing.assert_allclose(half, 0.2)
    assert "simulation truth (on the estimate's line)" not in legend_labels(a)
    np.testing.assert_allclose(line(b, "simulation truth (on the estimate's line)")[:, 1], [0.05, 1.05, 2.45])


def test_fig6_7_station_estimation_plots_first_and_last_sweeps(tmp_path):
    from types import SimpleNamespace as NS

    a = np.linspace(0, 360, 5)
    y = np.linspace(-10, 10, 5)
    centres = [NS(sweeps=[(a, a * 0.1), (a, a * 0.01)], iterations=3, error_um=(3.0, 4.0)) for _ in range(2)]
    zeros = [NS(sweeps=[(y, y * 2.0), (y + 5, y * 0.1)], error_rad=12e-6, std_rad=5e-6) for _ in range(2)]
    with captured_figures() as figs:
        figures.plot_station_estimation(centres, zeros, tmp_path / "f67.png")
    first, last, zero = figs["f67.png"].axes
    assert legend_labels(first) == ["Pos A: target put near the axis", "Pos B: target put near the axis"]
    assert legend_labels(last)[0] == "Pos A: after 2 moves (error 5.0 µm)"
    np.testing.assert_allclose(line(last, "Pos B: after 2 moves (error 5.0 µm)"), np.column_stack([a, a * 0.01]))
    np.testing.assert_allclose(line(zero, "Pos A: first setting"), np.column_stack([y, y * 2.0]))
    np.testing.assert_allclose(line(zero, "Pos A: final (+12 µrad off, u 5 µrad)"), np.column_stack([y, y * 0.1]))
    assert zero.get_xlabel() == "Y across the beam, mm" and "001 Fig. 7" in zero.get_title()
