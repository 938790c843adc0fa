"""The multilateration of 001 as one position model + the shared distance measurement + a named gauge on the one
``Calibration`` (issue 22 item 1): the free points of 001 (2D/3D, tool offsets), their Jacobian against finite
differences, and ``Multilateration`` the same program as the free points through ``Calibration``. Units: mm."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import Calibration, SolverOptions
from olti_drake.estimation.multilateration import Multilateration, MultilaterationOptions, _gauge_rows, machine_campaign
from olti_drake.model.budget import paper001_budget
from olti_drake.model.free_points import FreePoints, fit_tool_offsets
from olti_drake.model.gauges import GAUGES_BY_DIM, NamedGauge, free_points_gauge
from olti_drake.model.machine import Machine3DScenario, MachineScenario, simulate_machine_campaign, \
    simulate_machine_campaign_3d
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.model.volumetric3d import MachineConfig

TOOLS_MM = ((0.0, 0.0, 100.0), (80.0, 0.0, 60.0))


@pytest.fixture(scope="module")
def campaigns():
    """The paper-001 2D table (seed 3) and a 3D campaign with two reflector mountings (offsets estimated)."""
    cols2, _ = simulate_machine_campaign(MachineScenario(seed=3), paper001_budget())
    cols3, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=3, config=MachineConfig(tool_offsets_mm=TOOLS_MM),
                                                              tools=(0, 1)))
    return {"2d": machine_campaign(cols2), "3d-tools": machine_campaign(cols3)}


def _general(data, ml, gauge_kind):
    """The free points of the campaign read by the shared distance measurement with the named gauge, on the
    general Calibration -- built from the campaign alone (the start stations: the multilateration's)."""
    model = FreePoints(data.commands_mm, data.tool, ml.tool_offsets_mm)
    stations, dead = ml._split(ml.x0)[1:]
    measurement = StationDistanceMeasurement(model, data.target, data.station, data.displacement_mm, stations, dead)
    gauge = free_points_gauge(gauge_kind, model.nominal_mm, len(measurement.names))
    return Calibration(measurement, SolverOptions(), gauge, data.source)


@pytest.mark.parametrize("case, gauge_kind", [("2d", "best-fit"), ("2d", "first-two"), ("3d-tools", "best-fit"),
                                              ("3d-tools", "first-three")])
def test_multilateration_is_the_free_points_through_calibration(campaigns, case, gauge_kind):
    data = campaigns[case]
    ml = Multilateration(data, MultilaterationOptions(gauge=gauge_kind))
    cal = _general(data, ml, gauge_kind)
    assert list(cal.names) == list(ml.names) and cal.gauge == ml.gauge
    np.testing.assert_array_equal(cal.x0, ml.x0)
    A1, b1 = ml._equality_rows()
    A2, b2 = cal._equality_rows()
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(b1, b2)
    rng = np.random.default_rng(1)
    for x in (ml.x0, ml.x0 + 1e-2 * rng.standard_normal(len(ml.x0))):
        r1, J1 = ml.residuals(x)
        r2, J2 = cal.residuals(x)
        assert np.abs(r1 - r2).max() <= 1e-12 and abs(J1 - J2).max() <= 1e-12
        np.testing.assert_allclose(ml.beam_lengths(x), cal.beam_lengths(x), rtol=0, atol=1e-12)
    # The batched rows (the Monte Carlo's) are the measurement's, and its CSR Jacobian theirs.
    X = ml.x0 + 1e-3 * rng.standard_normal((3, len(ml.x0)))
    for a, b in zip(ml.residual_rows(X), cal.measurement.residual_rows(X)):
        np.testing.assert_array_equal(a, b)
    f1, f2 = ml.fit(), cal.fit()
    assert np.abs(f1.x - f2.x).max() <= 1e-12 and np.abs(f1.std - f2.std).max() <= 1e-12
    assert cal.layout(f2.x) == ml.layout(f1.x)
    assert list(cal.layout(f2.x)) == ["targets_mm", "stations_mm", "dead_paths_mm"]


def test_free_points_jacobian_against_finite_differences(campaigns):
    data = campaigns["3d-tools"]
    ml = Multilateration(data)
    model = ml.model
    assert model.names[:4] == ("p0_x_mm", "p0_y_mm", "p0_z_mm", "p1_x_mm") and model.dim == 3
    np.testing.assert_array_equal(model.start_vector(), (data.commands_mm + ml.tool_offsets_mm[data.tool]).ravel())
    rng = np.random.default_rng(2)
    x = model.start_vector() + rng.standard_normal(model.n_params)
    p, jac = model.jacobian(x)
    J = jac.tocsr().toarray()  # rows x, y, z of point 0, then point 1, ...
    h = 1e-6
    fd = np.column_stack([(model.positions(x + h * e).ravel() - model.positions(x - h * e).ravel()) / (2 * h)
                          for e in np.eye(model.n_params)])
    assert J.shape == fd.shape and np.abs(J - fd).max() < 1e-8
    # The distance rows u · dp/dx (the serial model's contract convention) and the batched rows agree with it.
    u = rng.standard_normal((model.n_points, 3))
    np.testing.assert_allclose(jac.contract(u).toarray(), np.einsum("mc,mcn->mn", u, fd.reshape(-1, 3, fd.shape[1])),
                               atol=1e-8)
    pts = data.target[:50]
    pb, cols, dp = model.rows(x[None], pts)
    np.testing.assert_array_equal(pb[0], p[pts])
    dense = np.zeros((len(pts), 3, model.n_params))
    for c in range(3):
        np.add.at(dense[:, c], (np.arange(len(pts))[:, None], cols), np.broadcast_to(dp[c], cols.shape))
    np.testing.assert_allclose(dense, fd.reshape(-1, 3, fd.shape[1])[pts], atol=1e-8)


@pytest.mark.parametrize("case", ["2d", "3d-tools"])
def test_distance_measurement_jacobian_against_finite_differences(campaigns, case):
    ml = Multilateration(campaigns[case])
    m = ml.measurement
    x = ml.x0 + 1e-3 * np.random.default_rng(3).standard_normal(len(ml.x0))
    r, J = m.residuals(x)
    h = 1e-5
    cols = np.random.default_rng(4).choice(len(x), 40, replace=False)
    cols = np.union1d(cols, [0, m.station_col, m.station_col + m.dim, m.dead_path_col, len(x) - 1])
    for k in cols:
        e = np.zeros(len(x))
        e[k] = h
        fd = (m.residuals(x + e)[0] - m.residuals(x - e)[0]) / (2 * h)
        np.testing.assert_allclose(J[:, k].toarray().ravel(), fd, atol=1e-7)


def test_named_gauges_are_the_gauge_rows_and_refuse_other_names(campaigns):
    for case, data in campaigns.items():
        ml = Multilateration(data)
        for kind in GAUGES_BY_DIM[data.dim]:
            g = free_points_gauge(kind, ml.nominal_mm, len(ml.names))
            assert isinstance(g, NamedGauge) and g.kind == kind
            A, b, sentence = _gauge_rows(kind, ml.nominal_mm, len(ml.names))
            np.testing.assert_array_equal(g.A, A)
            np.testing.assert_array_equal(g.b, b)
            assert g.sentence == sentence
    with pytest.raises(InputError, match="gauge must be one of best-fit, first-three for a 3D campaign, got "
                                         "'first-two'"):
        free_points_gauge("first-two", campaigns["3d-tools"].commands_mm, 10)


def test_tool_offsets_are_found_relative_to_tool_0_by_the_model(campaigns):
    data = campaigns["3d-tools"]
    ml = Multilateration(data)
    assert np.abs(ml.tool_offsets_mm[1] - ml.tool_offsets_mm[0] - [80.0, 0.0, -40.0]).max() < 0.01
    # Exact readings of known stations: the offset comes back to rounding.
    P = np.array([[-300.0, -250.0, -50.0], [700.0, -200.0, 0.0], [650.0, 550.0, 80.0], [-250.0, 500.0, -120.0]])
    L0 = np.array([100.0, 120.0, 90.0, 110.0])
    cmd = np.random.default_rng(5).uniform(0, 300, (20, 3))
    tools = np.repeat([0, 1], 10)
    target, station = np.repeat(np.arange(20), 4), np.tile(np.arange(4), 20)
    t_true = np.array([[0.0, 0.0, 0.0], [30.0, -20.0, 55.0]])
    reading = np.linalg.norm(cmd[target] + t_true[tools[target]] - P[station], axis=1) - L0[station]
    t = fit_tool_offsets(cmd, tools, target, station, reading, P, L0, 2)
    np.testing.assert_allclose(t, t_true, atol=1e-9)


def test_implausible_values_are_the_measurement_then_the_model(campaigns):
    ml = Multilateration(campaigns["2d"])
    x = ml.x0.copy()
    assert ml.implausible(x) == []
    x[0] += 1e4  # target 0 far off its command
    x[ml.measurement.station_col] += 1e7  # station 0 far from everything
    said = ml.implausible(x)
    assert len(said) == 2 and said[0].startswith("station 0 lies") and said[1].startswith("target 0 is estimated")
    assert ml.model.implausible(x[:ml.model.n_params]) == said[1:]
