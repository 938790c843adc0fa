"""The program is the problem (issue 12): ``Solve(ident.prog)`` identifies the model, as the default LM does.

The data cost ½Σr² (analytic gradient), the start (initial guess) and the gauge live on the
MathematicalProgram a user receives; a user's own variables, constraints and costs work in both paths.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")
TOL = 1e-6  # mm / deg


@pytest.fixture(scope="module")
def data():
    import olti_drake

    return olti_drake.load_campaign(CAMPAIGN)


def _ident(data, model, **kw):
    import olti_drake

    return olti_drake.Identifier(data, olti_drake.IdentificationOptions(model=model, check_resolution=False, **kw))


@pytest.mark.parametrize("model", ["errormap", "dh"])
def test_solve_prog_with_the_default_solver_equals_lm(data, model):
    from pydrake.solvers import Solve

    lm = _ident(data, model).solve()
    ident = _ident(data, model)
    result = Solve(ident.prog)  # the program alone: its data cost, initial guess and gauge
    assert result.is_success(), result.get_solution_result()
    x = result.GetSolution(ident.variables)
    assert np.abs(x - lm.x).max() < TOL, (result.get_solver_id().name(), np.abs(x - lm.x).max())
    # The start is the program's initial guess, and the data cost evaluates to ½Σr² there.
    assert np.array_equal(ident.prog.GetInitialGuess(ident.variables), ident.x0)
    r = ident.residuals(lm.x)[0]
    assert ident.prog.EvalBinding(ident.data_cost, lm.x)[0] == pytest.approx(0.5 * np.sum(r * r), rel=1e-12)


@pytest.mark.parametrize("name", ["SnoptSolver", "IpoptSolver"])
def test_solve_prog_by_solver_name_equals_lm(data, name):
    import pydrake.solvers as ps

    solver = getattr(ps, name)()
    if not solver.available():
        pytest.skip(f"{name} is not available in this pydrake wheel")
    lm = _ident(data, "dh").solve()
    ident = _ident(data, "dh")
    options = ps.SolverOptions()
    # IPOPT is within TOL after ~200 iterations and then runs on to its cap of 3000 without meeting its own
    # dual-infeasibility tolerance (measured: 2.7e-7 at 200, 500 and 1000 iterations): 200 keeps the suite short.
    options.SetOption(ps.IpoptSolver.id(), "max_iter", 200)
    result = solver.Solve(ident.prog, None, options)
    x = result.GetSolution(ident.variables)
    assert np.abs(x - lm.x).max() < TOL, (name, result.get_solution_result(), np.abs(x - lm.x).max())
    if name == "SnoptSolver":
        assert result.is_success()
    # IPOPT (L-BFGS Hessian in Drake) reaches the minimum within TOL but may stop at its iteration cap
    # before its own dual-infeasibility tolerance is met: the parameters are checked, not its status.


def _shared_offset(ident):
    """A user variable: one dead-path offset shared by reflectors 0 and 1 (d0_0 = d0_1 = offset)."""
    from pydrake.symbolic import Variable

    offset = Variable("offset_mm")
    ident.prog.AddDecisionVariables([offset])
    d0 = [ident.variables[ident.names.index(f"d0_{j}_mm")] for j in (0, 1)]
    for v in d0:
        ident.prog.AddLinearEqualityConstraint(v - offset == 0)
    return offset


@pytest.mark.parametrize("solver", ["lm", "nlp"])
def test_user_variable_tied_by_a_linear_constraint(data, solver):
    ident = _ident(data, "dh", solver=solver)
    _shared_offset(ident)
    res = ident.solve()  # IndexError before issue 12
    assert res.value("d0_0_mm") == pytest.approx(res.value("d0_1_mm"), abs=1e-9)
    free = _ident(data, "dh").solve()
    assert abs(free.value("d0_0_mm") - free.value("d0_1_mm")) > 1e-3  # the constraint changed something
    fit = ident.fit() if solver == "nlp" else None
    if fit is not None:
        assert fit.extra["offset_mm"] == pytest.approx(res.value("d0_0_mm"), abs=1e-6)


def test_user_variable_same_answer_in_both_paths(data):
    out = {}
    for solver in ("lm", "nlp"):
        ident = _ident(data, "dh", solver=solver)
        _shared_offset(ident)
        out[solver] = ident.fit()
    # The dh model leaves mm residuals on this campaign (u ~ 1 mm): both solvers' stopping tests allow
    # ~1e-5 u (the relative cost tolerance 1e-12); they must agree far below u.
    lm, nlp = out["lm"], out["nlp"]
    assert np.all(np.abs(lm.x - nlp.x) <= 1e-4 * lm.std + TOL)
    i = lm.names.index("d0_0_mm")
    assert lm.extra["offset_mm"] == pytest.approx(nlp.extra["offset_mm"], abs=1e-4 * lm.std[i] + TOL)
    assert out["lm"].extra["offset_mm"] == pytest.approx(out["lm"].x[out["lm"].names.index("d0_0_mm")], abs=1e-9)


def _circle_constraint(ident, radius):
    """A nonlinear user constraint: reflector 0 on a circle of ``radius`` mm about the origin."""
    v = {n: ident.variables[ident.names.index(n)] for n in ("P0_x_mm", "P0_y_mm")}
    b = ident.prog.AddConstraint(v["P0_x_mm"] ** 2 + v["P0_y_mm"] ** 2 == radius ** 2)
    b.evaluator().set_description("reflector 0 on a circle")


def test_nonlinear_user_constraint_solved_by_nlp_and_refused_by_lm(data):
    from olti_drake.errors import InputError

    free = _ident(data, "dh").solve()
    radius = float(np.hypot(*free.reflectors_mm[0])) + 0.05  # 50 um off the free fit: the constraint binds
    ident = _ident(data, "dh", solver="nlp")
    _circle_constraint(ident, radius)
    res = ident.solve()
    assert np.hypot(*res.reflectors_mm[0]) == pytest.approx(radius, abs=1e-6)
    lm = _ident(data, "dh")
    _circle_constraint(lm, radius)
    with pytest.raises(InputError, match=r"'lm' solver takes linear.*reflector 0 on a circle.*solver='nlp'"):
        lm.solve()


def test_multilateration_same_targets_lm_nlp_and_within_uncertainty_of_truth(tmp_path):
    from pydrake.solvers import Solve

    from olti_drake.estimation.multilateration import (Multilateration, MultilaterationOptions, align_to_commands,
                                                       machine_campaign)
    from olti_drake.io.budget import default_budget
    from olti_drake.model.machine import MachineScenario, simulate_machine_campaign

    cols, truth = simulate_machine_campaign(MachineScenario())
    data = machine_campaign(cols)
    lm = Multilateration(data).solve(default_budget("machine"))
    nlp = Multilateration(data, MultilaterationOptions(solver="nlp")).solve(default_budget("machine"))
    assert np.abs(lm.targets_mm - nlp.targets_mm).max() < TOL
    prog = Multilateration(data)
    x = Solve(prog.prog).GetSolution(prog.variables)
    assert np.abs(x - lm.fit.x).max() < TOL
    targets = align_to_commands(truth["targets_mm"], truth["commands_mm"])
    err = np.hypot(*(lm.targets_mm - targets).T)
    assert np.all(err < 3 * np.hypot(*lm.targets_std_mm.T))


def test_public_names_at_the_top_and_import_stays_light():
    code = ("import sys, olti_drake; assert 'pydrake' not in sys.modules, 'pydrake imported';"
            "from olti_drake import Identifier, IdentificationOptions, load_campaign;"
            "assert 'pydrake' not in sys.modules; print(Identifier.__module__, load_campaign.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["olti_drake.estimation.identification", "olti_drake.io.csvio"]


def test_calibration_over_the_serial_chain_model_solves_a_synthetic_campaign():
    """The N-joint chain plugs in as another position model: Calibration(DistanceMeasurement) recovers a
    truth of the model family from its noise-free readings, by LM and by Solve(prog), with no change to
    the program."""
    from pathlib import Path

    import olti_drake
    from pydrake.solvers import Solve

    from olti_drake.estimation.calibration import Calibration
    from olti_drake.estimation.calibration import SolverOptions
    from olti_drake.model.chain import load_serial_chain
    from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign,
                                         synthetic_truth)

    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    ranges = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                       [-180.0, 180.0]])
    truth = synthetic_truth(chain, seed=3, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, 200, seed=12, ranges_deg=ranges, directions=False)
    model = build_position_model(chain, camp.commands, None, kind="dh", tool_offset_mm=(40.0, -25.0, 60.0))
    meas = DistanceMeasurement(model, camp.distance_commands, None, camp.station, camp.displacement_mm,
                               truth.stations_mm, truth.dead_paths_mm)
    gauge = find_gauge(meas)
    rng = np.random.default_rng(13)
    x_true = meas.start_vector() + np.where([n.endswith("_mm") for n in meas.names], 0.3, 0.05) * rng.normal(
        size=len(meas.names))
    x_true -= np.linalg.lstsq(gauge.A, gauge.A @ x_true - gauge.b, rcond=None)[0]  # obey the gauge
    meas.displacement = meas.predict(x_true)
    fit = Calibration(meas, SolverOptions(), gauge, "synthetic UR5").fit()
    assert np.abs(fit.x - x_true).max() < 1e-6
    assert np.abs(fit.residuals).max() < 1e-8
    cal = Calibration(meas, SolverOptions(), gauge, "synthetic UR5")
    x = Solve(cal.prog).GetSolution(cal.variables)
    assert np.abs(x - x_true).max() < 1e-5


def test_uncertainty_with_a_user_variable_follows_its_constraint(data):
    """Linear propagation and Monte Carlo with a user variable: the trials obey the user's constraint
    (d0_0 = d0_1 through the shared offset) and the two methods agree on the parameters' u."""
    from olti_drake.estimation.uncertainty import linear_covariance, monte_carlo
    from olti_drake.io.budget import default_budget
    from olti_drake.model.budget import ReadingErrors

    ident = _ident(data, "dh")
    _shared_offset(ident)
    res = ident.solve()
    errors = ReadingErrors(default_budget("scara"))
    u = np.sqrt(np.diag(linear_covariance(ident, res.x, errors)))
    mc = monte_carlo(ident, res.x, errors, trials=500, seed=1, workers=1)
    k0, k1 = ident.names.index("d0_0_mm"), ident.names.index("d0_1_mm")
    assert np.abs(mc.samples[:, k0] - mc.samples[:, k1]).max() < 1e-9
    assert u[k0] == pytest.approx(u[k1], rel=1e-9)
    assert mc.samples.std(axis=0) == pytest.approx(u, rel=0.2)



def test_suspect_readings_are_named_by_file_line_and_coordinate():
    """The summaries' one line of a fit's outliers (every kind's): file line, a point's coordinate, sigma; the rest
    counted."""
    from olti_drake.estimation.calibration import suspect_readings_line

    assert suspect_readings_line([]) == "" and suspect_readings_line(None) == ""
    out = [{"line": 12, "normalized": -9.1}, {"line": 40, "coordinate": "y", "normalized": 5.04}]
    assert suspect_readings_line(out) == ("  2 suspect reading(s) beyond the outlier threshold: line 12 (-9.1 sigma), "
                                          "line 40 y (+5.0 sigma)")
    many = [{"line": k, "normalized": 4.0} for k in range(13)]
    assert suspect_readings_line(many).endswith("line 9 (+4.0 sigma) and 3 more")
