"""The volumetric machine as a position model of the one engine (issue 22 item 1): the tool points of a 3D
campaign's targets on the 21 ISO 230-1 error motions, squareness and tool-offset errors
(:class:`VolumetricPositionModel`, the held motions taken out), read by the shared distance measurement (001
Eq. (3), :class:`StationDistanceMeasurement`) under the representation's gauge (:func:`volumetric_gauge`) in a
plain :class:`~olti_drake.estimation.calibration.Calibration` is :class:`VolumetricIdentification`; the position
model's analytic Jacobian equals central differences and its batched rows its Jacobian. Units: mm, µrad.
"""

import numpy as np
import pytest
import scipy.sparse as sp

from olti_drake.estimation.calibration import Calibration, SolverOptions, station_fit
from olti_drake.estimation.multilateration import machine_campaign
from olti_drake.estimation.volumetric import VolumetricIdentification, VolumetricOptions
from olti_drake.model.gauges import VOLUMETRIC_GAUGE_CONDITIONS, volumetric_gauge
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.model.volumetric3d import MachineConfig, VolumetricModel, VolumetricPositionModel, motion_unit

TOOLS_MM = ((0.0, 0.0, 100.0), (150.0, 0.0, 100.0), (0.0, 150.0, 140.0))


@pytest.fixture(scope="module")
def campaigns():
    """Simulated pan/tilt campaigns (001 Eq. (1) in 3D, Table 4 noise) of a 5 x 4 x 4 grid: three tools (every
    motion separable, tool offsets identified) and one tool (four angular motions held at 0)."""
    cfg = MachineConfig(tool_offsets_mm=TOOLS_MM, knot_spacing_mm=100.0)
    out = {}
    for name, tools in (("3 tools", (0, 1, 2)), ("1 tool", (0,))):
        cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(5, 4, 4), tools=tools, seed=4))
        out[name] = machine_campaign(cols, f"machine ({name})")
    return out


def _options(data):
    return VolumetricOptions(tool_offsets_mm=TOOLS_MM[:data.n_tools])  # the default knots of the grid


def _general(data, vi):
    """The volumetric model of the campaign read by the shared distance measurement under the representation's
    gauge, on the general Calibration -- built by hand (the held motions and start stations: the identification's
    observability and station fits)."""
    config = vi.config
    model = VolumetricModel(config, identify_tool_offsets=len(config.tools) > 1)
    position = VolumetricPositionModel(model, data.commands_mm, data.tool, held=tuple(vi.held))
    nominal = data.commands_mm + config.tools[data.tool]
    fits = [station_fit(nominal[data.target[data.station == j]], data.displacement_mm[data.station == j])
            for j in range(data.n_stations)]
    measurement = StationDistanceMeasurement(position, data.target, data.station, data.displacement_mm,
                                             np.array([f[0] for f in fits]), np.array([f[1] for f in fits]),
                                             data.n_stations, dead_path="L0")
    gauge = volumetric_gauge(len(measurement.names))
    assert gauge.A.shape == (0, len(measurement.names)) and gauge.conditions == VOLUMETRIC_GAUGE_CONDITIONS
    cal = Calibration(measurement, SolverOptions(), None, data.source)
    return cal, gauge


def _eq3(vi, x):
    """001 Eq. (3) written out densely on the model (r_k = ‖p(q_i, t_m; θ) − P_j‖ − L0_j − ΔL_k, mm) and its
    Jacobian: the oracle."""
    d = vi.data
    theta, P, L0 = vi.split(x)
    p, J = vi.model.jacobian(d.commands_mm, d.tool, theta)
    diff = p[d.target] - P[d.station]
    dist = np.linalg.norm(diff, axis=1)
    u = diff / dist[:, None]
    K, n_j = len(dist), d.n_stations
    A = np.zeros((K, len(vi.names)))
    A[:, :vi.n_model] = np.einsum("kc,kcp->kp", u, J[:, :, vi.free_cols][d.target])
    for c in range(3):
        A[np.arange(K), vi.n_model + 3 * d.station + c] = -u[:, c]
    A[np.arange(K), vi.n_model + 3 * n_j + d.station] = -1.0
    return dist - L0[d.station] - d.displacement_mm, A


def _perturbed(vi, rng, size=1.0):
    """x0 plus a machine's worth of errors: µm on linear coefficients and tool offsets, µrad on angular ones
    and the squareness, tens of µm on the stations and dead paths."""
    units = [motion_unit(n.split("[")[0]) if n.startswith("E_") and "[" in n else
             ("urad" if n.endswith("_urad") else "mm") for n in vi.names[:vi.n_model]]
    scale = np.array([3e-3 if u == "mm" else 4.0 for u in units] + [0.02] * (len(vi.names) - vi.n_model))
    return vi.x0 + size * scale * rng.standard_normal(len(vi.names))


@pytest.mark.parametrize("case", ["3 tools", "1 tool"])
def test_volumetric_identification_is_the_position_model_through_calibration(campaigns, case):
    data = campaigns[case]
    vi = VolumetricIdentification(data, _options(data))
    assert bool(vi.held) == (case == "1 tool")  # one tool: the motions it cannot separate are held
    cal, gauge = _general(data, vi)
    assert list(cal.names) == list(vi.names) and vi.gauge == gauge.sentence
    assert not vi.prog.GetAllConstraints() and not cal.prog.GetAllConstraints()  # fixed in the representation
    np.testing.assert_array_equal(cal.x0, vi.x0)
    np.testing.assert_array_equal(vi.free_cols, cal.measurement.model.free_cols)
    assert vi.n_model == cal.measurement.model.n_params
    rng = np.random.default_rng(1)
    for x in (vi.x0, _perturbed(vi, rng)):
        r1, J1 = vi.residuals(x)
        r2, J2 = cal.residuals(x)
        r3, J3 = _eq3(vi, x)
        assert np.abs(r1 - r2).max() <= 1e-12 and abs(J1 - J2).max() <= 1e-12
        assert np.abs(r1 - r3).max() <= 1e-12 and np.abs(J1.toarray() - J3).max() <= 1e-12
        np.testing.assert_allclose(vi.beam_lengths(x), cal.beam_lengths(x), rtol=0, atol=1e-12)
        assert cal.layout(x) == vi.layout(x) and list(vi.layout(x)) == ["model", "stations_mm", "dead_paths_mm"]
    # Physically impossible values: the same phrases (a station 100 travel diagonals away, a motion of metres).
    bad = vi.x0.copy()
    bad[vi.n_model] += 1e6
    bad[0] += 5e4
    said = vi.implausible(bad)
    assert said == cal.implausible(bad) and "the travel diagonal" in said[0] and "reaches" in said[1]
    f1, f2 = vi.fit(), cal.fit()
    assert np.abs(f1.x - f2.x).max() <= 1e-12 and np.abs(f1.std - f2.std).max() <= 1e-12
    assert np.abs(f1.residuals - f2.residuals).max() <= 1e-12
    np.testing.assert_array_equal(vi.theta(f1.x)[vi.free_cols], f1.x[:vi.n_model])
    assert not np.any(np.delete(vi.theta(f1.x), vi.free_cols))  # held motions 0


def test_volumetric_position_model_jacobian_against_finite_differences(campaigns):
    data = campaigns["1 tool"]
    vi = VolumetricIdentification(data, _options(data))
    model = vi.position_model
    assert model.dim == 3 and model.names == tuple(vi.names[:vi.n_model]) and model.held == tuple(vi.held)
    np.testing.assert_array_equal(model.start_vector(), np.zeros(model.n_params))
    rng = np.random.default_rng(2)
    x = _perturbed(vi, rng)[:vi.n_model]
    p, jac = model.jacobian(x)
    np.testing.assert_array_equal(p, model.positions(x))
    J = jac.tocsr().toarray()  # rows x, y, z of point 0, then point 1, ...
    # Every entry of the analytic model Jacobian is in the compressed pattern (fixed by the commands).
    _, full = vi.model.jacobian(data.commands_mm, data.tool, model.theta(x))
    np.testing.assert_array_equal(J, full[:, :, model.free_cols].reshape(-1, model.n_params))
    h = 1e-3  # mm or µrad
    fd = np.column_stack([(model.positions(x + h * e).ravel() - model.positions(x - h * e).ravel()) / (2 * h)
                          for e in np.eye(model.n_params)])
    assert np.abs(J - fd).max() <= 1e-8  # mm/mm, mm/µrad
    # contract: the distance rows u_k · ∂p_k/∂x; take: the points of the readings.
    u = rng.standard_normal((model.n_points, 3))
    np.testing.assert_allclose(jac.contract(u).toarray(), np.einsum("kc,kcp->kp", u, J.reshape(-1, 3, model.n_params)),
                               rtol=0, atol=1e-12)
    k = data.target[:7]
    np.testing.assert_array_equal(jac.take(k).tocsr().toarray(), J.reshape(-1, 3, model.n_params)[k].reshape(21, -1))
    # The batched rows (the measurement's) are the Jacobian at every parameter vector, on columns shared by all.
    X = np.stack([x, _perturbed(vi, rng, 2.0)[:vi.n_model]])
    pr, cols, dp = model.rows(X, data.target)
    for t in range(len(X)):
        pt, jt = model.jacobian(X[t])
        np.testing.assert_array_equal(pr[t], pt[data.target])
        dense = np.stack([sp.csr_matrix((dp[c][t].ravel(), cols.ravel(), np.arange(len(cols) + 1) * cols.shape[1]),
                                        shape=(len(cols), model.n_params)).toarray() for c in range(3)], axis=1)
        np.testing.assert_array_equal(dense, jt.tocsr().toarray().reshape(-1, 3, model.n_params)[data.target])
