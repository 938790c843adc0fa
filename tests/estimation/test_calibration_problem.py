"""The program before the solve, for every kind (issue 22): ``od.calibration_problem`` builds the calibration of
a SCARA, a six-axis distance or tracker campaign, a 3D multilateration, a volumetric and a five-axis machine; SNOPT
and IPOPT on ``problem.prog`` (scaled unknowns) and Gauss-Newton steps through Clarabel reach LM's cost within 1e-6
(IPOPT not on the five-axis machine: PAIRS), and
``problem.identification`` gives the kind's result with the same checks; the user's additions are honoured by
every path or refused by name."""

import numpy as np
import pytest

import olti_drake as od
from olti_drake.errors import InputError
from tests.estimation.test_five_axis_identify import TRUNNION

PAPER = "data/paper000/campaign.csv"
TOOL = (40.0, -25.0, 60.0)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Seeded campaigns not planned by the tool: six-axis random poses (4 stations; tracker points) of a truth
    with maps and backlash (outside the dh family); a 3D machine of smooth sine motions read open loop by pan/tilt
    heads (outside the volumetric spline family), on a small grid for the multilateration."""
    from olti_drake.io.csvio import write_machine_campaign
    from olti_drake.io.serial_io import load_robot, write_serial_campaign
    from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d
    from olti_drake.model.serial import synthetic_campaign, synthetic_truth
    from olti_drake.model.volumetric3d import MachineConfig

    d = tmp_path_factory.mktemp("kinds")
    truth = synthetic_truth(load_robot("ur5", "tool0"), seed=3, tool_offset_mm=TOOL)
    camp = synthetic_campaign(truth, 150, seed=4, noise_mm=1e-3)
    write_serial_campaign(d / "distance.csv", camp.distance_commands, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    write_serial_campaign(d / "points.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    tools = ((0.0, 0.0, 100.0), (150.0, 0.0, 100.0), (0.0, 150.0, 140.0))
    cfg = MachineConfig(tool_offsets_mm=tools, knot_spacing_mm=100.0)
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(3, 3, 3), tools=(0,), seed=4))
    write_machine_campaign(cols, d / "machine_small.csv")
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(5, 4, 4), tools=(0, 1, 2), seed=4))
    write_machine_campaign(cols, d / "machine.csv")
    from olti_drake.io.five_axis_io import write_five_axis_campaign
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_truth import synthetic_truth as five_axis_truth
    from tests.estimation.test_five_axis_identify import TABLE_STATIONS, distance_campaign, no_dropped_truth

    machine = FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")  # (40 random commands, 4 table stations)
    truth5 = no_dropped_truth(five_axis_truth(machine, seed=3))
    write_five_axis_campaign(d / "five_axis.csv", distance_campaign(machine, truth5, 40, 4, TABLE_STATIONS, "workpiece"))
    return d


def _problem(files, case):
    if case == "scara":
        return od.calibration_problem(PAPER, model="errormap")
    if case in ("six_axis_distance", "six_axis_tracker"):
        f = files / ("distance.csv" if case.endswith("distance") else "points.csv")
        return od.calibration_problem(f, model="dh", robot="ur5", tool_frame="tool0", tool_offset_mm=TOOL)
    if case == "multilateration_3d":
        return od.calibration_problem(files / "machine_small.csv", model="multilateration")
    if case == "five_axis":
        return od.calibration_problem(files / "five_axis.csv", model="geometric", machine=TRUNNION,
                                      workpiece_frame="workpiece", tool_frame="tool")
    tools = "0,0,100;150,0,100;0,150,140"
    return od.calibration_problem(files / "machine.csv", model="volumetric",
                                  tool_offsets_mm=[[float(v) for v in t.split(",")] for t in tools.split(";")])


def _cost(result) -> float:
    fit = getattr(result, "fit", result)
    r = fit.residuals if hasattr(fit, "residuals") else fit.residuals_mm
    return 0.5 * float(np.sum(np.square(r)))


def _x(result):
    return getattr(result, "fit", result).x


CASES = ("scara", "six_axis_distance", "six_axis_tracker", "multilateration_3d", "volumetric", "five_axis")
#: IPOPT (Drake's: a limited-memory Hessian) on the five-axis campaign's scaled program (condition number 1e4 within
#: the gauge) creeps -- 1.1x LM's cost after 100 iterations (the unknowns scaled by the data's and the prior's
#: curvature; by the data's alone 14x) -- and stops at its limit of 3000 (~200 s): its result is refused by name
#: (problem.identification: "did not succeed (kIterationLimit)"); SNOPT (1.7 s) and Clarabel's steps reach LM.
PAIRS = [(c, s) for c in CASES for s in ("snopt", "ipopt", "clarabel") if (c, s) != ("five_axis", "ipopt")]


@pytest.fixture(scope="module")
def lm(files):
    """LM's result of every case (the CLI's default fit)."""
    return {case: _problem(files, case).fit() for case in CASES}


@pytest.mark.parametrize("case,solver", PAIRS)
def test_every_solver_reaches_lm_on_the_scaled_program(files, lm, case, solver):
    from pydrake.solvers import ClarabelSolver, IpoptSolver, SnoptSolver

    problem = _problem(files, case)
    assert problem.prog.GetInitialGuess(problem.variables) == pytest.approx(0.0)  # the start, z = 0
    if solver == "clarabel":
        result = problem.gauss_newton(ClarabelSolver())
    else:
        result = (SnoptSolver() if solver == "snopt" else IpoptSolver()).Solve(problem.prog)
    assert result.is_success(), result.get_solution_result()
    ident = problem.identification(result)
    assert type(ident) is type(lm[case])
    assert abs(_cost(ident) - _cost(lm[case])) <= 1e-6 * _cost(lm[case])
    fit = getattr(ident, "fit", ident)
    assert fit.solver.startswith("given: ") and "scaled program" in fit.solver
    # The same covariance machinery: the uncertainties agree with LM's to the solution's difference.
    std, std_lm = getattr(ident, "fit", ident).std, getattr(lm[case], "fit", lm[case]).std
    np.testing.assert_allclose(std, std_lm, rtol=1e-3)


def test_the_problem_fit_is_the_engine_fit(files):
    """calibration_problem(...).fit() is identify()'s answer (the CLI's): the same program, solved by LM."""
    from olti_drake.estimation.identification import IdentificationOptions, identify
    from olti_drake.io.csvio import load_campaign

    mine = od.calibration_problem(PAPER, model="dh").fit()
    ref = identify(load_campaign(PAPER), IdentificationOptions(model="dh"))
    np.testing.assert_array_equal(mine.x, ref.x)
    assert mine.names == ref.names


def test_the_scaled_unknowns_are_named_and_map_to_parameters(files):
    """z[name] = (x − x0)/s with s = 1/‖∂r/∂x‖: columns of the scaled Jacobian of unit length; parameter()
    is the parameter in model units as a linear expression."""
    problem = _problem(files, "volumetric")
    assert [v.get_name() for v in problem.variables[:2]] == [f"z[{n}]" for n in problem.names[:2]]
    J = problem.program.residuals(problem.x0)[1].toarray() * problem.scale
    norms = np.linalg.norm(J, axis=0)
    np.testing.assert_allclose(norms[norms > 0], 1.0, rtol=1e-12)
    # µrad and mm side by side: the scales differ by orders of magnitude, the scaled columns do not.
    assert problem.scale.max() / problem.scale.min() > 1e3
    e = problem.parameter(problem.names[5])
    assert e.Evaluate({problem.variables[5]: 2.0}) == pytest.approx(problem.x0[5] + 2.0 * problem.scale[5])
    with pytest.raises(InputError, match="no parameter 'L9_mm'"):
        problem.parameter("L9_mm")


def test_a_user_constraint_and_variable_are_honoured_by_every_path(files):
    """L1 fixed at 325 mm and both reflectors' dead paths tied to one user variable: LM, SNOPT and the
    Gauss-Newton steps give the same solution, every one of them on the constraints."""
    from pydrake.solvers import ClarabelSolver, SnoptSolver

    def build():
        p = od.calibration_problem(PAPER, model="dh")
        p.prog.AddLinearEqualityConstraint(p.parameter("L1_mm") == 325.0)
        offset = p.prog.NewContinuousVariables(1, "offset")[0]
        for j in (0, 1):
            p.prog.AddLinearEqualityConstraint(p.parameter(f"d0_{j}_mm") - offset == 0.0)
        return p

    results = [build().fit()]
    p = build()
    results.append(p.identification(SnoptSolver().Solve(p.prog)))
    p = build()
    results.append(p.identification(p.gauss_newton(ClarabelSolver())))
    for res in results:
        x = dict(zip(res.names, res.x))
        assert x["L1_mm"] == pytest.approx(325.0, abs=1e-9)
        assert x["d0_0_mm"] == pytest.approx(x["d0_1_mm"], abs=1e-9)
        assert res.extra["offset(0)"] == pytest.approx(x["d0_0_mm"], abs=1e-9)  # the user's variable, reported
        assert res.uncertainty("L1_mm") < 1e-6  # fixed: no uncertainty left
    free = od.calibration_problem(PAPER, model="dh").fit()
    assert abs(free.value("L1_mm") - 325.0) > 1e-4  # (the constraint did something)
    for res in results[1:]:
        np.testing.assert_allclose(res.x, results[0].x, atol=1e-6)


def test_nonlinear_additions_are_refused_by_name_where_they_cannot_be_honoured(files):
    from pydrake.solvers import ClarabelSolver

    p = od.calibration_problem(PAPER, model="dh")
    x, y = p.parameter("P0_x_mm"), p.parameter("P0_y_mm")
    p.prog.AddConstraint(x * x + y * y == 650.0 ** 2 + 450.0 ** 2).evaluator().set_description("radius")
    with pytest.raises(InputError, match=r"nonlinear .*'radius' on z\[P0_x_mm\], z\[P0_y_mm\]"):
        p.fit()
    with pytest.raises(InputError, match="not linear"):
        p.gauss_newton(ClarabelSolver())


def test_a_failed_solve_is_refused_not_reported(files):
    from pydrake.solvers import SnoptSolver

    p = od.calibration_problem(PAPER, model="errormap")
    p.prog.SetSolverOption(SnoptSolver.id(), "Major iterations limit", 1)
    result = SnoptSolver().Solve(p.prog)
    assert not result.is_success()
    with pytest.raises(InputError, match="did not succeed"):
        p.identification(result)


def test_options_and_kinds_are_named(files):
    with pytest.raises(InputError, match="takes no option 'grid_step_deg'"):
        od.calibration_problem(PAPER, model="errormap", grid_step_deg=10.0)
    with pytest.raises(InputError, match="model must be"):
        od.calibration_problem(PAPER, model="spline")
    with pytest.raises(InputError, match="tool frame"):
        od.calibration_problem(files / "distance.csv", model="dh", robot="ur5")
    with pytest.raises(InputError, match="takes no robot"):
        od.calibration_problem(files / "machine.csv", model="volumetric", robot="ur5")
