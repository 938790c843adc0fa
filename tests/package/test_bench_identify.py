"""The identification benchmark's generator and scipy baseline are right (no timing assertions).

A small version of the benchmark's 1 deg problem: a 5 deg map grid and 2000
synthetic readings. Units: mm, deg.
"""

import importlib.util
import os

import numpy as np
import pytest

from olti_drake.estimation.identification import Identifier, identify
from olti_drake.sim.scenario import Scenario

_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "benchmarks", "bench_identify.py")
_spec = importlib.util.spec_from_file_location("bench_identify", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

STEP_DEG, N_READINGS = 5.0, 2000


@pytest.fixture(scope="module")
def small():
    data, truth = bench.synthetic_campaign(N_READINGS, STEP_DEG, seed=3)
    opts = bench.grid_options(STEP_DEG)
    return data, truth, opts


def test_generator_is_seeded_and_on_the_lattice(small):
    data, truth, _ = small
    again, _ = bench.synthetic_campaign(N_READINGS, STEP_DEG, seed=3)
    other, _ = bench.synthetic_campaign(N_READINGS, STEP_DEG, seed=4)
    assert np.array_equal(data.displacement_mm, again.displacement_mm)
    assert not np.array_equal(data.displacement_mm, other.displacement_mm)
    c = data.commands
    assert len(data) == N_READINGS
    for theta, (lo, hi) in ((c.theta1_deg, bench.J1_RANGE_DEG), (c.theta2_deg, bench.J2_RANGE_DEG)):
        assert theta.min() >= lo and theta.max() <= hi
        assert np.allclose(theta, np.round(theta / STEP_DEG) * STEP_DEG)
    assert set(np.unique(data.reflector)) == {0, 1, 2}
    assert np.array_equal(truth["reflectors_mm"], np.asarray(Scenario().reflectors_mm, dtype=float))


def test_generator_readings_follow_the_truth(small):
    data, truth, _ = small
    c = data.commands
    p = Scenario().robot.true_robot().end_effector(c.theta1_deg, c.theta2_deg, c.dir1, c.dir2)
    P, d0 = truth["reflectors_mm"][data.reflector], truth["dead_paths_mm"][data.reflector]
    noise = data.displacement_mm - (np.hypot(*(p - P).T) - d0)
    assert np.std(noise) == pytest.approx(bench.NOISE_MM, rel=0.1)
    assert abs(np.mean(noise)) < 4 * bench.NOISE_MM / np.sqrt(N_READINGS)


def test_every_map_node_is_touched_in_both_directions(small):
    data, _, opts = small
    c = data.commands
    for grid, theta, direction in ((opts.grid1_deg, c.theta1_deg, c.dir1), (opts.grid2_deg, c.theta2_deg, c.dir2)):
        for sign in (1.0, -1.0):
            assert set(grid) <= set(theta[direction == sign])
    assert bench.untouched_parameters(Identifier(data, opts)) == []


def test_generator_refuses_too_few_readings():
    with pytest.raises(ValueError, match="cannot touch"):
        bench.synthetic_campaign(100, 1.0)


@pytest.mark.parametrize("tr_solver", ["lsmr", "exact"])
def test_scipy_baseline_reaches_the_cost_of_identify(small, tr_solver):
    data, _, opts = small
    ident = Identifier(data, opts)
    ours = identify(data, opts)
    sci = bench.scipy_solve(ident, tr_solver)
    assert sci["rms_mm"] == pytest.approx(ours.residual_rms_mm, rel=1e-6)
    assert 0.8 * bench.NOISE_MM < ours.residual_rms_mm < 1.1 * bench.NOISE_MM
    # The gauge was eliminated, not ignored: scipy's solution obeys the program's constraint.
    assert sci["eliminated"] and all(n.startswith("J1_") for n in sci["eliminated"])
    for b in ident.prog.linear_equality_constraints():
        idx = ident.prog.FindDecisionVariableIndices(b.variables())
        assert b.evaluator().GetDenseA() @ sci["x"][idx] == pytest.approx(b.evaluator().lower_bound(), abs=1e-12)
    assert np.max(np.abs(sci["x"] - ours.x) / ours.std) < 0.05


def test_gauge_elimination_maps_onto_the_constraint(small):
    data, _, opts = small
    ident = Identifier(data, opts)
    T, x_fix, free, eliminated = bench.gauge_elimination(ident)
    n = len(ident.names)
    assert T.shape == (n, n - 1) and len(free) == n - 1 and len(eliminated) == 1
    z = np.random.default_rng(0).standard_normal(n - 1)
    x = x_fix + T @ z
    assert np.array_equal(x[free], z)
    (b,) = ident.prog.linear_equality_constraints()
    idx = ident.prog.FindDecisionVariableIndices(b.variables())
    assert b.evaluator().GetDenseA() @ x[idx] == pytest.approx(b.evaluator().lower_bound(), abs=1e-12)


def test_scipy_baseline_dh_needs_no_gauge_and_matches(small):
    data, _, _ = small
    opts = bench.IdentificationOptions(model="dh")
    ident = Identifier(data, opts)
    assert bench.gauge_elimination(ident)[3] == []
    assert bench.scipy_solve(ident, "exact")["rms_mm"] == pytest.approx(identify(data, opts).residual_rms_mm,
                                                                         rel=1e-6)


def test_scipy_baseline_stops_at_its_time_limit(small):
    data, _, opts = small
    with pytest.raises(bench.ScipyTimeout):
        bench.scipy_solve(Identifier(data, opts), time_limit_s=0.0)


def test_phase_timer_times_inherited_methods_and_restores_them(small):
    """The split sees the LeastSquaresProgram methods Identifier inherits (LM, steps, covariance) and leaves
    the classes as they were."""
    from olti_drake.estimation.calibration import LeastSquaresProgram

    data, _, opts = small
    _, total, split, calls = bench.timed_split(lambda: identify(data, opts))
    assert calls["_step"] >= 1 and calls["_finish"] >= 1 and calls["check_identifiability"] >= 1
    assert split["identifiability check + covariance"] > 0 and split["LM step programs: build (Identifier._step)"] > 0
    assert sum(split.values()) == pytest.approx(total)
    for name in ("_solve_lm", "_step", "_finish", "within", "accept"):
        assert name not in vars(Identifier) and getattr(Identifier, name) is getattr(LeastSquaresProgram, name)


_SERIAL_PATH = os.path.join(os.path.dirname(_PATH), "bench_serial_identify.py")
_serial_spec = importlib.util.spec_from_file_location("bench_serial_identify", _SERIAL_PATH)
serial_bench = importlib.util.module_from_spec(_serial_spec)
_serial_spec.loader.exec_module(serial_bench)


def test_serial_benchmark_problem_is_seeded_and_at_its_scale():
    meas, gauge = serial_bench.problem("six-axis")
    again, _ = serial_bench.problem("six-axis")
    assert np.array_equal(meas.displacement, again.displacement)
    assert len(meas.station) == 4 * 700 and 150 <= len(meas.names) <= 250  # ~200 unknowns
    assert gauge.A.shape[1] == len(meas.names)


def test_serial_scipy_baseline_reaches_the_cost_of_ours():
    """The six-axis problem: scipy (gauge eliminated) and our Calibration reach the same least-squares cost,
    and scipy's solution obeys the gauge."""
    meas, gauge = serial_bench.problem("six-axis")
    _, fit = serial_bench.ours(meas, gauge)
    _, sci = serial_bench.scipy_lsmr(meas, gauge)
    assert sci["rms_mm"] == pytest.approx(serial_bench.rms(fit.residuals), rel=serial_bench.SAME_COST_RTOL)
    assert np.abs(gauge.A @ sci["x"] - gauge.b).max() < 1e-9
