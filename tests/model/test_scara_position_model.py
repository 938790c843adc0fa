"""The SCARA closed form of paper 000 as a position model of the one engine (issue 22): Eq. (3) with Eq. (4) or
Eq. (7)-(9) (:class:`ScaraPositionModel`) read by the shared distance measurement (Eq. 5 / 10,
:class:`StationDistanceMeasurement`) under its gauge (:func:`scara_gauge`) in a plain
:class:`~olti_drake.estimation.calibration.Calibration` is the SCARA :class:`Identifier`; its batched analytic
Jacobian equals central differences. Units: mm, deg.
"""

import os

import numpy as np
import pytest

from olti_drake.estimation.calibration import Calibration, SolverOptions, station_fit
from olti_drake.estimation.identification import IdentificationOptions, Identifier
from olti_drake.io.csvio import load_campaign
from olti_drake.model.errormap import ErrorMap
from olti_drake.model.gauges import scara_gauge
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.model.scara import JointCommands, ScaraModel, ScaraPositionModel

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")


@pytest.fixture(scope="module")
def data():
    return load_campaign(CAMPAIGN)


def _robot(data, model):
    """The start of the identification built by hand: nominal lengths, zero maps on the distinct commands."""
    if model == "dh":
        return ScaraModel(325.0, 225.0, 0.0)
    c = data.commands
    maps = [ErrorMap(g, np.zeros(g.size), np.zeros(g.size), axis=axis)
            for axis, g in (("J1", np.unique(c.theta1_deg)), ("J2", np.unique(c.theta2_deg)))]
    return ScaraModel(325.0, 225.0, None, *maps)


def _general(data, model, poses=False):
    """Calibration(StationDistanceMeasurement(ScaraPositionModel)) with the SCARA gauge, the reflectors started by
    station fits on the nominal model; ``poses``: the model on the distinct poses, each reading naming its own."""
    robot = _robot(data, model)
    c = data.commands
    n_t = data.n_reflectors
    p = robot.positions(c)
    fits = [station_fit(p[data.reflector == j], data.displacement_mm[data.reflector == j]) for j in range(n_t)]
    P, d0 = np.array([f[0] for f in fits]), np.array([f[1] for f in fits])
    if poses:
        table = np.column_stack([c.theta1_deg, c.theta2_deg, c.dir1, c.dir2])
        unique, points = np.unique(table, axis=0, return_inverse=True)
        assert len(unique) < len(table)  # the campaign repeats poses (one per reflector)
        position = ScaraPositionModel(robot, JointCommands(*unique.T))
        points = points.ravel()
    else:
        position = ScaraPositionModel(robot, c)
        points = position.all_poses
    measurement = StationDistanceMeasurement(position, points, data.reflector, data.displacement_mm, P, d0, n_t,
                                             dead_path="d0")
    gauge = scara_gauge(robot, len(measurement.names))
    return Calibration(measurement, SolverOptions(), gauge if len(gauge.b) else None, data.source), gauge


@pytest.mark.parametrize("model", ["errormap", "dh"])
@pytest.mark.parametrize("poses", [False, True], ids=["per-reading", "distinct-poses"])
def test_calibration_of_the_scara_position_model_is_the_identifier(data, model, poses):
    ident = Identifier(data, IdentificationOptions(model=model, check_resolution=False))
    general, gauge = _general(data, model, poses)
    assert general.names == ident.names
    assert gauge.sentence == ident.gauge
    assert np.abs(general.x0 - ident.x0).max() <= 1e-12
    X = ident.x0 + 1e-3 * np.sin(np.arange(len(ident.x0)))[None] * np.arange(1, 4)[:, None]
    (r0, c0, v0), (r1, c1, v1) = ident.residual_rows(X), general.residual_rows(X)
    assert np.abs(r0 - r1).max() <= 1e-12
    assert np.abs(v0 - v1).max() <= 1e-12 and np.array_equal(c0, c1)
    assert abs(ident.residuals(X[1])[1] - general.residuals(X[1])[1]).max() <= 1e-12
    a, b = ident.fit(), general.fit()
    for name in ("x", "std", "residuals"):
        assert np.abs(getattr(a, name) - getattr(b, name)).max() <= 1e-12, name
    assert a.iterations == b.iterations and a.outliers == b.outliers
    mine, theirs = general.layout(a.x), ident.layout(a.x)
    assert np.abs(np.subtract(mine["stations_mm"], theirs["reflectors_mm"])).max() <= 1e-12
    assert np.abs(np.subtract(mine["dead_paths_mm"], theirs["dead_paths_mm"])).max() <= 1e-12
    assert mine["L1_mm"] == theirs["L1_mm"]


def _random_point(model: ScaraPositionModel, rng):
    """A parameter vector near the start: lengths within 1 mm, θ20 or map nodes within 0.05 deg."""
    x = model.start_vector() + np.concatenate([rng.uniform(-1.0, 1.0, 2),
                                               rng.uniform(-0.05, 0.05, model.n_params - 2)])
    return x


@pytest.mark.parametrize("model", ["errormap", "dh"])
def test_batched_jacobian_of_the_position_model_equals_central_differences(data, model):
    rng = np.random.default_rng(7)
    position = ScaraPositionModel(_robot(data, model), data.commands)
    points = rng.choice(position.n_points, 300)  # readings of some poses, repeated and out of order
    X = np.array([_random_point(position, rng) for _ in range(3)])
    p, cols, (dx, dy) = position.rows(X, points)
    assert p.shape == (3, 300, 2) and cols.shape[0] == 300 and dx.shape == dy.shape == (3, 300, cols.shape[1])
    h = 1e-5  # mm / deg: central differences, truncation ~1e-13, rounding ~1e-9 mm per mm or deg
    for t in range(len(X)):
        analytic = np.zeros((300, 2, position.n_params))
        for c, d in enumerate((dx, dy)):
            np.add.at(analytic[:, c], (np.arange(300)[:, None], cols), d[t])  # a one-node map sums its weights
        numeric = np.zeros_like(analytic)
        for i in range(position.n_params):
            step = np.zeros((1, X.shape[1]))
            step[0, i] = h
            numeric[:, :, i] = (position.rows(X[t:t + 1] + step, points)[0][0]
                                - position.rows(X[t:t + 1] - step, points)[0][0]) / (2 * h)
        assert np.abs(analytic - numeric).max() <= 1e-7 * max(1.0, np.abs(analytic).max())
        # the positions and the Jacobian object at one x, in the shared sparse conventions
        q, jac = position.jacobian(X[t])
        assert np.abs(q[points] - p[t]).max() <= 1e-12
        assert np.abs(jac.take(points).tocsr().toarray().reshape(300, 2, -1) - analytic).max() <= 1e-12
        u = rng.standard_normal((300, 2))
        assert np.abs(jac.take(points).contract(u).toarray() - np.einsum("kc,kcn->kn", u, analytic)).max() <= 1e-12
    assert position.positions() == pytest.approx(position.robot.positions(data.commands), abs=0)


def test_position_model_layout_and_implausible_values(data):
    position = ScaraPositionModel(_robot(data, "errormap"), data.commands)
    x = position.start_vector()
    values, unc = position.layout(x), position.layout(x, uncertainty=True)
    assert values["L1_mm"] == 325.0 and "grid_deg" in values["error_map"]["J1"]
    assert "grid_deg" not in unc["error_map"]["J2"]
    assert position.implausible(x) == []
    bad = x.copy()
    bad[0], bad[5] = 700.0, 12.0
    assert position.implausible(bad) == [
        "L1 = 700 mm is more than 2 x off its nominal 325 mm (readings in mm? the right --nominal-mm?)",
        f"{position.names[5]} = 12 deg is beyond 10 deg, no positioning deviation"]
