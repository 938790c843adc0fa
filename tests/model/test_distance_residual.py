"""One distance residual: the serial robot's :class:`~olti_drake.model.serial.DistanceMeasurement` and the
row-compressed :func:`~olti_drake.model.measurements.distance_rows_nd` of the other position models give the
same r = ‖p − P_j‖ − d0_j − d (000 Eq. 10, 001 Eq. 3, mm) and the same Jacobian on the same points and
stations, to 1e-12: in 3D (a six-axis arm), with dead-path drift, and for a planar robot's in-plane stations."""

from pathlib import Path

import numpy as np
import pytest

import olti_drake
from olti_drake.model.chain import load_serial_chain, planar_axis
from olti_drake.model.measurements import distance_rows_nd
from olti_drake.model.scara import rows_to_csr
from olti_drake.model.serial import (DistanceMeasurement, build_position_model, synthetic_campaign,
                                     synthetic_truth)

MODELS = Path(olti_drake.__file__).parent / "models"
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])


def _rows_of(meas, x, readings):
    """distance_rows_nd on the measurement's points p (M, 3) with their ∂p/∂x and its stations (3D columns)."""
    pm, nt = meas.model.n_params, len(meas.labels)
    xm, P, _ = meas._parts(x)
    p, jp = meas.model.jacobian(meas.commands, meas.dirs, xm)
    dense = jp.tocsr().toarray()  # rows x, y, z of reading 0, then reading 1, ...
    dp = [dense[c::3][None] for c in range(3)]
    d0 = x[pm + len(meas._free) * nt:pm + (len(meas._free) + 1) * nt]
    r, cols, vals = distance_rows_nd(p[None], np.broadcast_to(np.arange(pm), (len(p), pm)), dp, P[None], d0[None], meas.station, readings,
                                     pm, pm + 3 * nt)
    return r[0], rows_to_csr(cols, vals[0], pm + 4 * nt).toarray()


@pytest.fixture(scope="module")
def six_axis():
    chain = load_serial_chain(MODELS / "ur5.urdf", "tool0")
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, 120, seed=4, ranges_deg=RANGES)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=30.0,
                                 tool_offset_mm=(40.0, -25.0, 60.0))
    return truth, camp, model


def _perturbed(meas, seed):
    x = meas.start_vector().copy()
    x += np.random.default_rng(seed).normal(scale=0.05, size=x.size)
    return x


def test_serial_distance_residual_is_distance_rows_nd_in_3d(six_axis):
    truth, camp, model = six_axis
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    x = _perturbed(meas, 1)
    r, jac = meas.residuals(x)
    r_nd, jac_nd = _rows_of(meas, x, meas.displacement)
    scale = max(np.abs(r).max(), 1.0)
    assert np.abs(r - r_nd).max() <= 1e-12 * scale
    assert np.abs(jac.toarray() - jac_nd).max() <= 1e-12 * max(np.abs(jac_nd).max(), 1.0)
    assert np.abs(meas.predict(x) - (r + meas.displacement)).max() <= 1e-12 * scale


def test_serial_distance_residual_with_drift_is_distance_rows_nd(six_axis):
    """d0_j(t) = d0_j + v_j (t − t̄_j): the drift is the serial measurement's own (its columns −(t − t̄_j));
    the residual is the shared one with the drifted dead path."""
    truth, camp, model = six_axis
    times = np.linspace(0.0, 6.0, len(camp.displacement_mm))
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm, time_h=times,
                               drift_mm_per_h=np.full(len(truth.dead_paths_mm), 0.002))
    x = _perturbed(meas, 2)
    r, jac = meas.residuals(x)
    pm, nt = model.n_params, len(meas.labels)
    v = x[pm + 4 * nt:]
    shift = v[meas.station] * meas._dt()  # the drift moves d0_j: the same as a reading larger by it
    r_nd, jac_nd = _rows_of(meas, x, meas.displacement + shift)
    jac = jac.toarray()
    assert np.abs(r - r_nd).max() <= 1e-12 * max(np.abs(r).max(), 1.0)
    assert np.abs(jac[:, :pm + 4 * nt] - jac_nd).max() <= 1e-12 * max(np.abs(jac_nd).max(), 1.0)
    expect = np.zeros((len(r), nt))
    expect[np.arange(len(r)), meas.station] = -meas._dt()
    assert np.abs(jac[:, pm + 4 * nt:] - expect).max() <= 1e-12


def test_planar_serial_distance_residual_is_distance_rows_nd():
    """A planar robot (models/scara.sdf to 'beam', plane z = 360 mm): stations held in the plane, their two free
    coordinates the serial measurement's own columns; r and ∂r/∂x equal distance_rows_nd's."""
    chain = load_serial_chain(MODELS / "scara.sdf", "beam")
    axis = planar_axis(chain)
    rng = np.random.default_rng(7)
    commands = np.column_stack([rng.uniform(-140, 60, 200), rng.uniform(0, 140, 200)])
    dirs = rng.choice([-1.0, 1.0], size=commands.shape)
    model = build_position_model(chain, commands, dirs, kind="errormap", grid_step_deg=20.0, planar=axis)
    station = np.repeat([0, 1, 2], len(commands) // 3 + 1)[:len(commands)]
    stations = np.array([[-600.0, 200.0, 360.0], [100.0, -650.0, 360.0], [700.0, 500.0, 360.0]])
    p = model.positions(commands, dirs)
    readings = np.linalg.norm(p - stations[station], axis=1) - 500.0 + rng.normal(scale=0.01, size=len(p))
    meas = DistanceMeasurement(model, commands, dirs, station, readings, stations, np.full(3, 500.0), plane=axis)
    x = _perturbed(meas, 3)
    r, jac = meas.residuals(x)
    pm, nt = model.n_params, 3
    r_nd, jac_nd = _rows_of(meas, x, meas.displacement)
    assert np.abs(r - r_nd).max() <= 1e-12 * max(np.abs(r).max(), 1.0)
    jac = jac.toarray()
    free = [pm + 3 * j + c for j in range(nt) for c in meas._free]
    keep = list(range(pm)) + free + [pm + 3 * nt + j for j in range(nt)]
    assert np.abs(jac - jac_nd[:, keep]).max() <= 1e-12 * max(np.abs(jac_nd).max(), 1.0)
