"""The calibration program before the solve, for every kind of robot and machine (``od.calibration_problem``).

One entry point builds the program of any campaign -- the SCARA of 000 (Eq. 5 / 10), an N-joint robot measured
by distances or a tracker, the multilateration of 001 (Eq. 2-6, 2D or 3D), the volumetric machine (21 ISO 230-1
motions) -- with the options of ``olti identify``, and hands it over *before* solving::

    import olti_drake as od
    from pydrake.solvers import Solve
    problem = od.calibration_problem("campaign.csv", model="errormap", robot="ur5", tool_frame="tool0")
    problem.prog                           # MathematicalProgram in the scaled unknowns (below)
    fit = problem.fit()                    # the default LM
    mine = problem.identification(Solve(problem.prog))   # the same result from any solver's

**The scaled unknowns.** The parameters sit side by side in mm, degrees and µrad, and the readings see them with
sensitivities six orders apart (a µrad of a machine's angular motion moves a reading by 10⁻⁴ mm, a mm of a link
by 1 mm): SNOPT, IPOPT and the conic solvers need unknowns of comparable scale. :attr:`CalibrationProblem.prog`'s
decision variables are therefore z_i = (x_i − x0_i) / s_i -- x the parameters in model units, x0 the start,
s_i = 1 / ‖∂r/∂x_i‖ at the start (every column of the scaled Jacobian of unit length; named ``z[<parameter>]``).
The start is z = 0 (the program's initial guess). Write constraints and costs in model units through
:meth:`CalibrationProblem.parameter` (a linear Drake expression of z)::

    L1 = problem.parameter("L1_mm")
    problem.prog.AddLinearEqualityConstraint(L1 == 325.0)       # L1 measured on a CMM, mm

Users may add decision variables, linear and quadratic costs and linear constraints of their own: every solver
path honours them -- LM (:meth:`CalibrationProblem.fit`, which carries them into the engine's program in model
units), any Drake solver on :attr:`prog`, and :meth:`CalibrationProblem.gauss_newton` (steps through a QP solver
such as Clarabel or OSQP). A nonlinear user constraint or cost is solved by the NLP solvers; LM and the
Gauss-Newton steps refuse it by name.

Whatever solved it, :meth:`CalibrationProblem.identification` turns a solver's result into the same
:class:`~olti_drake.estimation.identified.Identification` as :meth:`CalibrationProblem.fit` -- for every kind
(``kind``, ``names``, ``x``, ``std``, ``covariance``, ``residuals``, ``document()``, ``write(path)``; the kind's own
result as ``result``) -- by the same identifiability check, covariance and acceptance as LM's (a solver that did
not succeed is refused, never reported).
"""

import os
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import NLP_MAJOR_ITERATIONS, NLP_OPTIMALITY_TOLERANCE, _StepProgram, _rms

#: IPOPT's limited-memory Hessian keeps min(unknowns, this) correction pairs: its default, 6, takes thousands of
#: iterations on the scaled problems' correlated unknowns (the volumetric 77: 41 s; with 100 pairs 12 s).
IPOPT_HISTORY = 500
#: Gauss-Newton (:meth:`CalibrationProblem.gauss_newton`) stops when a step predicts less than this fraction of
#: the cost (the same bound as LM's on small problems).
GN_DECREASE = 1e-12


@dataclass
class Kind:
    """One kind of calibration: how a campaign becomes the engine's program and how a fit becomes its result."""

    name: str
    #: (campaign path, options dict) -> (program, finish, campaign): ``finish(pristine)`` solves the program (or takes the
    #: solution given to it, :meth:`LeastSquaresProgram.given_solution`) and returns the kind's result;
    #: ``pristine``: nothing was added to the program, so the kind may re-build it around its first fit.
    build: Callable
    what: str
    #: result -> its fit: what carries names, x, std (k = 1), covariance, residuals (mm), notes, warnings,
    #: converged_by, lack_of_fit_mm (the engine's ``Fit``, or the SCARA's ``Identification``, which has them).
    fit: Callable = lambda result: result.fit
    #: (result, problem, path) -> the result document ``olti identify`` writes to ``path`` for this kind, by the
    #: kind's writer in :mod:`olti_drake.io` (the files it names relative to ``path``'s folder).
    document: Callable = None


def _options(cls, o: dict, what: str):
    """``cls(**o)``, an option the kind does not take refused by name."""
    import dataclasses

    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(o) - known)
    if unknown:
        raise InputError(f"calibration_problem: {what} takes no option {unknown[0]!r} (its options: "
                         f"{', '.join(sorted(known))})")
    return cls(**o)


def _budget(o: dict, default: Optional[str] = None):
    """The budget option as an object: a file is read; None stays None, or the kind's default budget."""
    from olti_drake.io.budget import budget_or_default, load_budget

    budget = o.get("budget")
    if isinstance(budget, str) or (budget is None and default is not None):
        return budget_or_default(budget, default) if default is not None else load_budget(budget)
    return budget


def _scara(campaign, o: dict):
    from olti_drake.estimation.identification import IdentificationOptions, Identifier, parse_grid
    from olti_drake.io.csvio import load_campaign

    for k in ("grid1_deg", "grid2_deg"):
        if isinstance(o.get(k), str):
            o[k] = parse_grid(o[k], k)
    o["budget"] = _budget(o)
    data = load_campaign(campaign)
    ident = Identifier(data, _options(IdentificationOptions, o, KINDS["scara"].what))
    return ident, lambda pristine=False: ident.solve(), data


def _serial(campaign, o: dict):
    from olti_drake.estimation.serial_identification import (SerialIdentificationOptions, check_serial_map_size,
                                                             serial_problem)
    from olti_drake.io.serial_io import load_robot, read_serial_campaign

    robot, frame = o.pop("robot"), o.pop("tool_frame", None)
    if not frame:
        raise InputError(f"robot {robot}: give the tool frame (tool_frame=NAME)")
    o["budget"] = _budget(o)
    options = _options(SerialIdentificationOptions, o, KINDS["serial"].what)
    chain = load_robot(robot, frame)
    data = read_serial_campaign(campaign, chain.n_joints, robot=robot)
    check_serial_map_size(data, options)
    return serial_problem(chain, data, options) + (data,)


def _multilateration(campaign, o: dict):
    from olti_drake.estimation.multilateration import Multilateration, MultilaterationOptions, load_machine_campaign

    o.pop("model")
    # budget "residuals": the standard uncertainties from the residual variance alone (olti multilaterate's).
    o["budget"] = budget = None if o.get("budget") == "residuals" else _budget(o, "machine")
    data = load_machine_campaign(campaign)
    ml = Multilateration(data, _options(MultilaterationOptions, o, KINDS["multilateration"].what))
    return ml, lambda pristine=False: ml.solve(budget), data


def _volumetric(campaign, o: dict):
    from olti_drake.estimation.multilateration import load_machine_campaign
    from olti_drake.estimation.volumetric import VolumetricIdentification, VolumetricOptions, volumetric_campaign

    o.pop("model")
    o["budget"] = budget = _budget(o, "machine")
    data = volumetric_campaign(load_machine_campaign(campaign))
    vi = VolumetricIdentification(data, _options(VolumetricOptions, o, KINDS["volumetric"].what))
    return vi, lambda pristine=False: vi.solve(budget), data


def _machine5(campaign, o: dict):
    from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
    from olti_drake.io.five_axis_io import read_five_axis_campaign
    from olti_drake.model.five_axis import FiveAxisMachine

    machine = FiveAxisMachine.from_file(o.pop("machine"), o.pop("workpiece_frame", None) or "workpiece",
                                        o.pop("tool_frame", None) or "tool")
    o["budget"] = _budget(o)
    options = _options(FiveAxisOptions, o, KINDS["machine5"].what)
    data = read_five_axis_campaign(campaign, machine)
    ident = FiveAxisIdentification(data, machine, options)
    return ident, lambda pristine=False: ident.fit(), data


def _itself(result):
    return result


def _scara_document(ident, problem, path) -> dict:
    from olti_drake.io.result import result_dict

    return result_dict(ident)


def _serial_document(ident, problem, path) -> dict:
    from olti_drake.io.serial_io import robot_reference, serial_result_dict

    chain = problem.program.measurement.model.chain
    return serial_result_dict(kind=problem.model, robot_file=robot_reference(problem.robot, path),
                              measurement=ident.measurement, fit=ident.fit, gauge=ident.gauge,
                              campaign_digest=problem.campaign.digest(), notes=list(chain.notes) + ident.notes,
                              program=problem.program)


def _machine_document(res, problem, path) -> dict:
    return res.to_dict()  # (MultilaterationResult's, VolumetricResult's: io.documents / io.volumetric_io)


def _machine5_document(fit, problem, path) -> dict:
    from olti_drake.io.five_axis_io import machine5_result_dict

    out_dir = os.path.dirname(os.path.abspath(os.fspath(path)))
    linear = problem.program.linear_from  # (the --linear result, named relative to the result: not identify/perfect)
    linear = os.path.relpath(os.path.abspath(linear.path), out_dir) if linear is not None else None
    return machine5_result_dict(problem.program, fit,
                                os.path.relpath(os.path.abspath(problem.options["machine"]), out_dir),
                                linear_reference=linear)


#: The kinds of calibration, by name: the one place that tells them apart (:func:`kind_of`).
KINDS = {
    "scara": Kind("scara", _scara, "the SCARA of paper 000 (model dh or errormap)", _itself, _scara_document),
    "serial": Kind("serial", _serial, "an N-joint robot from its model file (robot=, tool_frame=)",
                   document=_serial_document),
    "multilateration": Kind("multilateration", _multilateration, "the machine-tool multilateration of 001",
                            document=_machine_document),
    "volumetric": Kind("volumetric", _volumetric, "the 21 ISO 230-1 motions of a 3-axis machine",
                       document=_machine_document),
    "machine5": Kind("machine5", _machine5, "a five-axis machine from its model file (machine=, model geometric or "
                                            "errormap)", _itself, _machine5_document),
}


def kind_of(model: str, robot: Optional[str] = None, machine: Optional[str] = None) -> Kind:
    """The kind a model name (and a robot file, for the N-joint robot; a machine file, for a five-axis machine)
    asks for."""
    if machine is not None:
        if robot is not None:
            raise InputError("a five-axis machine (--machine FILE) takes no robot (--robot)")
        if model not in ("geometric", "errormap"):
            raise InputError(f"model {model!r}: a five-axis machine (--machine FILE) takes --model geometric or errormap")
        return KINDS["machine5"]
    if model == "geometric":
        raise InputError("model 'geometric' is a five-axis machine's model: give its model file (--machine FILE; "
                         "machine=FILE in calibration_problem)")
    if model in ("multilateration", "volumetric"):
        if robot is not None:
            raise InputError(f"model={model!r} is a machine-tool model: it takes no robot")
        return KINDS[model]
    if model not in ("dh", "errormap"):
        raise InputError(f"model must be dh, errormap, multilateration or volumetric, got {model!r}")
    return KINDS["serial" if robot is not None else "scara"]


def calibration_problem(campaign, model: str = "errormap", robot: Optional[str] = None, **options):
    """The calibration program of ``campaign`` (a CSV file, formats.md) before the solve.

    ``model``: ``dh`` | ``errormap`` (the SCARA of 000 without ``robot``; an N-joint robot with ``robot`` = a
    URDF/SDFormat file or a shipped name and ``tool_frame``), ``multilateration`` (001, 2D or 3D) or
    ``volumetric``; with ``machine`` = a five-axis machine model file (and ``workpiece_frame``, ``tool_frame``)
    ``geometric`` or ``errormap``. ``options``: those of ``olti identify`` by their option names (mm, degrees), e.g.
    ``grid_step_deg``, ``tool_offset_mm``, ``compliance``, ``drift`` (N-joint), ``grid1_deg`` (SCARA, a grid
    text or array), ``nominal_L1_mm``, ``reflectors_mm``, ``fix_reflectors``, ``stations_mm``, ``gauge``,
    ``tool_offsets_mm`` (machines), ``knot_spacing_mm``, ``topology``, ``pitch_mm`` (volumetric); solver
    options ``loss``, ``huber_k``, ``outlier_threshold``, ``regularize``, ``max_iterations``, ``budget`` (a
    budget file or object; for the multilateration also ``"residuals"``: u from the residual variance alone).
    An unknown option is refused by name."""
    kind = kind_of(model, robot, options.get("machine"))
    o = dict(options, model=model)
    if robot is not None:
        o["robot"] = robot
    program, finish, data = kind.build(str(campaign), o)
    return CalibrationProblem(program, finish, kind.name, data, model=model, robot=robot, options=dict(options),
                              source=str(campaign))


class CalibrationProblem:
    """The program of a calibration in scaled unknowns (module doc), its LM fit and the result of any solver.

    ``program``: the engine's :class:`~olti_drake.estimation.calibration.LeastSquaresProgram` (model units);
    ``finish``: solves it (or takes a given solution) and returns the kind's result; ``kind``: its name;
    ``campaign``: the campaign as read (the kind's campaign type: its rows, lines, digest); ``model``, ``robot``,
    ``options``, ``source``: what :func:`calibration_problem` was given (the model name, the robot file or name,
    the options, the campaign file) -- the result document names them."""

    def __init__(self, program, finish, kind: str, campaign=None, model: Optional[str] = None,
                 robot: Optional[str] = None, options: Optional[dict] = None, source: Optional[str] = None):
        self.program, self._finish, self.kind, self.campaign = program, finish, kind, campaign
        self.model, self.robot, self.options, self.source = model, robot, dict(options or {}), source
        self.names = list(program.names)
        self.x0 = np.asarray(program.x0, dtype=float).copy()
        self._prog = None  # built when first read: a fit alone (the CLI's) needs no scaled program

    @property
    def prog(self):
        """The MathematicalProgram in the scaled unknowns z (module doc): the data cost, the model's constraints
        (gauge, fixed values) in z, the initial guess z = 0, solver options for SNOPT and IPOPT."""
        if self._prog is None:
            self._build()
        return self._prog

    @property
    def variables(self) -> np.ndarray:
        """The scaled unknowns z, named ``z[<parameter>]``, in the order of :attr:`names`."""
        self.prog
        return self._variables

    @property
    def scale(self) -> np.ndarray:
        """s_i, model units per scaled unit: 1/sqrt(‖∂r/∂x_i‖² + λ P_ii) at the start -- the data's curvature and,
        with the maps' smoothness prior ½ λ xᵀPx, the prior's (1 for a parameter neither touches)."""
        self.prog
        return self._scale

    def _build(self) -> None:
        from pydrake.solvers import IpoptSolver, MathematicalProgram, SnoptSolver
        from pydrake.symbolic import Variable

        program = self.program
        J = program.residuals(self.x0)[1]
        curvature = np.asarray(J.multiply(J).sum(axis=0)).ravel()
        # With the maps' smoothness prior its curvature counts too: a coefficient the readings barely see is held
        # by the prior, and scaled by the readings alone it would stretch the cost along it (a five-axis campaign's
        # linear splines: IPOPT at 4x LM's cost after 300 iterations).
        state = program.smoothing_weight() if program.smoothing_rows() is not None else None
        if state is not None:
            curvature = curvature + state["weight"] * np.diag(state["P"])
        norms = np.sqrt(curvature)
        self._scale = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
        self._prog = prog = MathematicalProgram()
        self._variables = np.array([Variable(f"z[{n}]") for n in self.names])
        prog.AddDecisionVariables(self._variables)
        self.data_cost = prog.AddCost(self._cost, self._variables)
        self.data_cost.evaluator().set_description("data: 1/2 sum of squared residuals (mm^2), scaled unknowns")
        prog.SetInitialGuess(self._variables, np.zeros(len(self.names)))
        # The bindings of the engine's program (not the user's) and those carried into it, by evaluator: kept
        # alive here, so that pybind hands out the same Python object for them and id() stays theirs.
        self._own, self._carried = {}, {}
        self._remember(self._own, self.data_cost.evaluator())
        for b in program.prog.GetAllConstraints():  # the gauge and fixed values, in z
            e = b.evaluator()
            idx = program.prog.FindDecisionVariableIndices(b.variables())
            A = e.GetDenseA()
            shift = A @ self.x0[idx]
            c = prog.AddLinearConstraint(A * self._scale[idx], e.lower_bound() - shift, e.upper_bound() - shift,
                                         self._variables[idx])
            c.evaluator().set_description(e.get_description() or "constraint of the model")
            self._remember(self._own, c.evaluator())
        if state is not None:
            # The maps' smoothness prior at its weight (chosen from the data once, by the engine): every solver of
            # prog solves the program LM fits. ½ λ (x0 + s z)ᵀ P (x0 + s z), its constant dropped.
            Sz = self._scale[:, None] * state["P"] * self._scale[None, :]
            c = prog.AddQuadraticCost(state["weight"] * Sz, state["weight"] * self._scale * (state["P"] @ self.x0),
                                      self._variables, is_convex=True)
            c.evaluator().set_description(state["binding"].evaluator().get_description())
            self._remember(self._own, c.evaluator())
        prog.SetSolverOption(SnoptSolver.id(), "Major optimality tolerance", NLP_OPTIMALITY_TOLERANCE)
        prog.SetSolverOption(SnoptSolver.id(), "Major iterations limit", NLP_MAJOR_ITERATIONS)
        prog.SetSolverOption(SnoptSolver.id(), "Iterations limit", 100 * NLP_MAJOR_ITERATIONS)
        # SNOPT keeps a limited-memory Hessian above 75 unknowns by default, which stalls on the correlated unknowns
        # of a machine model (the volumetric 77: iteration limit after 39 s; full memory: 2.7 s).
        prog.SetSolverOption(SnoptSolver.id(), "Hessian full memory", "")
        prog.SetSolverOption(IpoptSolver.id(), "limited_memory_max_history", min(len(self.names), IPOPT_HISTORY))

    @staticmethod
    def _remember(table: dict, evaluator) -> None:
        table[id(evaluator)] = evaluator

    # -- the unknowns ------------------------------------------------------------------------------
    def parameter(self, name: str):
        """Parameter ``name`` in model units (mm, deg, µrad as named) as a linear Drake expression of the scaled
        unknowns: x0 + s z -- for constraints and costs on :attr:`prog`."""
        if name not in self.names:
            raise InputError(f"no parameter {name!r} in this calibration (see problem.names)")
        i = self.names.index(name)
        return self.x0[i] + self.scale[i] * self.variables[i]

    def x(self, result) -> np.ndarray:
        """The parameters (model units) of a solver's result on :attr:`prog`."""
        return self.x0 + self.scale * result.GetSolution(self.variables)

    def _cost(self, z):
        """½ Σ r(x0 + s z)², mm²; its gradient s ⊙ Jᵀr for AutoDiffXd."""
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        ad = z.dtype == object
        r, J = self.program.residuals(self.x0 + self.scale * (ExtractValue(z).ravel() if ad else np.asarray(z, float)))
        f = 0.5 * float(r @ r)
        return AutoDiffXd(f, (self.scale * (J.T @ r)) @ ExtractGradient(z)) if ad else f

    # -- the user's additions, carried into the engine's program ------------------------------------
    def _user_bindings(self):
        """The bindings the user added to :attr:`prog`."""
        return [b for b in list(self.prog.GetAllConstraints()) + list(self.prog.GetAllCosts())
                if id(b.evaluator()) not in self._own]

    @property
    def pristine(self) -> bool:
        """Nothing added to :attr:`prog` by the user: a kind may then re-build its program around the first fit
        (the N-joint robot's tool point, its stations' sides) as ``olti identify`` does."""
        return self._prog is None or not self._user_bindings()

    def _carry(self) -> None:
        """The user's variables, linear constraints and linear/quadratic costs of :attr:`prog`, in model units, into
        the engine's program (once each): z = (x − x0)/s is affine, so each carries over exactly. A nonlinear one is
        refused by name (solve :attr:`prog` with an NLP solver and take :meth:`identification`)."""
        from pydrake.solvers import (BoundingBoxConstraint, LinearConstraint, LinearCost, QuadraticCost)

        if self._prog is None:
            return
        eng = self.program.prog
        index = {v.get_id(): i for i, v in enumerate(self.variables)}
        for v in self.prog.decision_variables()[len(self.names):]:
            if not any(v.EqualTo(w) for w in eng.decision_variables()):
                eng.AddDecisionVariables([v])
        for b in self._user_bindings():
            e = b.evaluator()
            if id(e) in self._carried:
                continue
            vs = list(b.variables())
            a = np.array([1.0 / self.scale[index[v.get_id()]] if v.get_id() in index else 1.0 for v in vs])
            c = np.array([-self.x0[index[v.get_id()]] / self.scale[index[v.get_id()]] if v.get_id() in index
                          else 0.0 for v in vs])  # (binding's variable) = a y + c, y the engine's variable
            ys = [self.program.variables[index[v.get_id()]] if v.get_id() in index else v for v in vs]
            if isinstance(e, (LinearConstraint, BoundingBoxConstraint)):
                A = e.GetDenseA()
                out = eng.AddLinearConstraint(A * a, e.lower_bound() - A @ c, e.upper_bound() - A @ c, ys)
            elif isinstance(e, QuadraticCost):
                Q = e.Q()
                out = eng.AddQuadraticCost(Q * np.outer(a, a), a * (Q @ c + e.b()), ys, is_convex=e.is_convex())
            elif isinstance(e, LinearCost):
                out = eng.AddLinearCost(a * e.a(), 0.0, ys)
            else:
                what = f"{type(e).__name__} {e.get_description()!r}" if e.get_description() else type(e).__name__
                raise InputError(f"the LM fit takes linear constraints and linear/quadratic costs only; problem.prog "
                                 f"has a nonlinear {what} on {', '.join(v.get_name() for v in vs)}: solve "
                                 f"problem.prog with an NLP solver (Solve, SNOPT, IPOPT) and take "
                                 f"problem.identification(result)")
            out.evaluator().set_description(e.get_description() or "user's")
            self._remember(self._carried, e)

    def inputs(self) -> list:
        """The files this calibration reads (campaign, budget, robot or machine model, ``linear`` result): never
        to be written over by a result (:meth:`Identification.write`)."""
        budget = self.options.get("budget")
        files = [self.source, budget if isinstance(budget, str) and budget != "residuals" else None,
                 self.robot, self.options.get("machine"), self.options.get("linear")]
        return [f for f in files if isinstance(f, (str, os.PathLike)) and os.path.exists(f)]

    # -- solving -------------------------------------------------------------------------------------
    def _identified(self, result):
        from olti_drake.estimation.identified import Identification

        return Identification(KINDS[self.kind], result, self)

    def fit(self):
        """The default LM fit (``olti identify``'s) with the user's additions to :attr:`prog`: an
        :class:`~olti_drake.estimation.identified.Identification` (the kind's own result as its ``result``)."""
        self._carry()
        return self._identified(self._finish(pristine=self.pristine))

    def identification(self, result, solver: Optional[str] = None):
        """The :class:`~olti_drake.estimation.identified.Identification` (the same type :meth:`fit` returns)
        from a solver's ``MathematicalProgramResult`` on :attr:`prog` (or from
        :meth:`gauss_newton`): the same identifiability check, covariance and acceptance as :meth:`fit`. A result
        that is not a success is refused in one line."""
        if not result.is_success():
            name = solver or _solver_name(result)
            raise InputError(f"the solver {name} did not succeed ({result.get_solution_result().name}): nothing to "
                             f"report")
        self._carry()
        zs = result.GetSolution(self.prog.decision_variables())
        x = self.x0 + self.scale * zs[:len(self.names)]
        eng = self.program.prog
        z = np.concatenate([x, np.zeros(eng.num_vars() - len(self.names))])
        for k, v in enumerate(self.prog.decision_variables()[len(self.names):]):
            z[eng.FindDecisionVariableIndex(v)] = zs[len(self.names) + k]
        name = solver or getattr(result, "label", None) or _solver_name(result)
        with self.program.given_solution(z, f"given: {name} on the scaled program"):
            return self._identified(self._finish(pristine=False))

    def gauss_newton(self, solver=None, max_iterations: int = 50):
        """Gauss-Newton on the scaled unknowns, each step a QP in the step δz solved by ``solver`` (a Drake solver
        object, e.g. ``ClarabelSolver()`` or ``OsqpSolver()``; default the one Drake picks): the linearized data
        cost ½‖r + J S δz‖² (S = diag(s)), the user's linear/quadratic costs and linear constraints of
        :attr:`prog` at z + δz; the step halved until the cost drops. Stops when a step predicts less than
        :data:`GN_DECREASE` of the cost. Returns the solution over :attr:`prog`'s variables
        (:class:`GaussNewtonResult`, read as Drake's, for :meth:`identification`); raises InputError when a step fails or the iterations run out."""
        from pydrake.solvers import Solve

        n_all, n = self.prog.num_vars(), len(self.names)
        z = np.asarray(self.prog.GetInitialGuess(self.prog.decision_variables()), dtype=float)
        z = np.where(np.isfinite(z), z, 0.0)
        steps = _StepProgram(self.prog, n_all, self.data_cost.evaluator(), None)
        data = self.data_cost.evaluator()
        users = [b for b in self.prog.GetAllCosts() if b.evaluator() is not data]

        def evaluate(zz):
            r, J = self.program.residuals(self.x0 + self.scale * zz[:n])
            return r, J, 0.5 * float(r @ r) + float(sum(self.prog.EvalBinding(b, zz)[0] for b in users))

        def solve(H, g):
            prog, _ = steps.at(z, H, g)
            out = Solve(prog) if solver is None else solver.Solve(prog)
            if not out.is_success():
                raise InputError(f"Gauss-Newton step: {_solver_name(out)} failed ({out.get_solution_result().name})")
            return out

        constraints = self.prog.GetAllConstraints()
        if constraints and not self.prog.CheckSatisfied(constraints, z, 1e-9):
            # Onto the constraints first, by the least change of z (as LM's start): from an infeasible point a
            # step that must also restore feasibility may raise the cost, and the halving would stop short of it.
            z = z + solve(np.eye(n_all), np.zeros(n_all)).get_x_val()
        r, J, cost = evaluate(z)
        for k in range(max_iterations):
            Js = (J @ sp.diags(self.scale)).toarray()
            H, g = np.zeros((n_all, n_all)), np.zeros(n_all)
            H[:n, :n], g[:n] = Js.T @ Js, Js.T @ r
            out = solve(H, g)
            name = _solver_name(out)
            delta = out.get_x_val()
            # The step program's optimum is the model's change of the cost (data and user costs) at z + δ.
            if -out.get_optimal_cost() <= GN_DECREASE * abs(cost):
                return GaussNewtonResult(self.prog, z, cost, name, k)
            for t in 0.5 ** np.arange(40):  # halve until the cost drops; none does at the rounding floor: done
                r_new, J_new, cost_new = evaluate(z + t * delta)
                if cost_new < cost:
                    break
            else:
                return GaussNewtonResult(self.prog, z, cost, name, k)
            z, r, J, cost = z + t * delta, r_new, J_new, cost_new
        raise InputError(f"Gauss-Newton did not converge in {max_iterations} steps (residual RMS "
                         f"{1e3 * _rms(r):.4g} um)")


class GaussNewtonResult:
    """What :meth:`CalibrationProblem.gauss_newton` found, read as a ``MathematicalProgramResult`` is read
    (``is_success``, ``GetSolution``, ``get_solution_result``, ``get_solver_id``, ``get_optimal_cost``) --
    Drake's result class cannot be filled from Python."""

    def __init__(self, prog, z, cost: float, solver_name: str, iterations: int):
        self._prog, self._z, self._cost = prog, np.asarray(z, dtype=float), cost
        self.label, self.iterations = f"Gauss-Newton steps by {solver_name}", iterations
        self._id = f"GN/{solver_name}"[:15]  # (Drake's recommended SolverId length)

    def is_success(self) -> bool:
        return True

    def GetSolution(self, variables):
        return self._z[self._prog.FindDecisionVariableIndices(list(np.ravel(variables)))]

    def get_x_val(self) -> np.ndarray:
        return self._z.copy()

    def get_optimal_cost(self) -> float:
        return self._cost

    def get_solution_result(self):
        from pydrake.solvers import SolutionResult

        return SolutionResult.kSolutionFound

    def get_solver_id(self):
        from pydrake.solvers import SolverId

        return SolverId(self._id)


def _solver_name(result) -> str:
    try:
        return result.get_solver_id().name()
    except Exception:  # (a result made by hand, e.g. gauss_newton's, has no solver id)
        return "the solver"
