"""Nonlinear least squares on a Drake MathematicalProgram -- the solver machinery the models share.

Paper 000 §3 (Eq. 5, 10) and paper 001 §2.3 (Eq. 2-6) are both "min Σ residual²"
over named parameters with a gauge. :class:`LeastSquaresProgram` holds one
Drake decision variable per parameter in :attr:`~LeastSquaresProgram.prog`
(users may add their own constraints and costs) and solves by

* ``lm`` (default): Levenberg-Marquardt; every step is a MathematicalProgram
  in the step δ -- the Gauss-Newton quadratic model plus the program's linear
  constraints and linear/quadratic costs shifted to δ -- solved by the solver
  Drake chooses (EqConstrainedQP for equality constraints only). Working in δ
  keeps full precision however large the parameters are.
* ``nlp``: the whole program -- it already carries the least-squares data
  cost (:attr:`~LeastSquaresProgram.data_cost`, value ½Σw r² with the analytic
  gradient Jᵀ(w r)) and the start as its initial guess -- handed to Drake's
  NLP solver (SNOPT/IPOPT); also takes nonlinear user constraints and costs.

So ``pydrake.solvers.Solve(problem.prog)`` (or any solver's ``Solve`` with its
options) solves the same problem as :meth:`~LeastSquaresProgram.fit`. Users may
add decision variables of their own (e.g. a shared offset tied by linear
constraints): both paths solve for them and report them in ``Fit.extra``.
LM takes linear constraints and linear/quadratic costs only; with a
nonlinear one it refuses with one line naming it (use ``solver='nlp'``).

Before solving it checks identifiability (parameters no reading touches, rank
deficiency within the constraints); after, it propagates the residual variance
(linear, JCGM 100) and flags outliers. Units are the subclass's (mm, deg).
"""

import contextlib
from dataclasses import dataclass, field
from typing import List

import numpy as np
import scipy.sparse as sp

from olti_drake.io.budget import ReadingErrors
from olti_drake.io.errors import InputError
from olti_drake.threads import single_thread_blas

#: Relative eigenvalue below which a parameter combination counts as unidentifiable.
RANK_TOLERANCE = 1e-12
#: Up to this many unknowns the dense algebra runs on one BLAS thread.
SMALL_PROBLEM = 300
#: Optimality tolerance set on the program for the NLP solvers (SNOPT, IPOPT), relative.
NLP_OPTIMALITY_TOLERANCE = 1e-8  # 1e-10: SNOPT ends "cannot be improved" (info 41), a failure, at the minimum
#: A residual RMS above this multiple of the reading uncertainty the budget predicts is a stated warning.
RESIDUAL_WARNING_RATIO = 3.0


class UnidentifiableError(InputError):
    """The campaign cannot determine the named parameters (listed in :attr:`names`)."""

    def __init__(self, message: str, names=()):
        super().__init__(message)
        self.names = list(names)


class FitRefused(InputError):
    """The solution is not one to trust -- not converged, singular or non-finite covariance, or physically
    impossible parameters. Raised before anything is written; the message is one line."""


@dataclass
class SolverOptions:
    """How to solve, for every model.

    ``loss``: ``l2`` or ``huber`` (IRLS, threshold ``huber_k`` robust sigmas).
    ``outlier_threshold``: report readings whose normalized residual exceeds it.
    ``regularize``: instead of stopping on unidentifiable parameters, add a
    weak prior pulling them to their initial value (and say so).
    ``solver``: ``lm`` or ``nlp``.
    """

    loss: str = "l2"
    huber_k: float = 3.0
    outlier_threshold: float = 4.0
    regularize: bool = False
    solver: str = "lm"
    max_iterations: int = 100
    #: Budget whose predicted reading uncertainty the residual RMS is checked against (None: the model's default).
    budget: object = None


@dataclass
class Fit:
    """A solved problem: x, standard uncertainties (k = 1), covariance, residuals, diagnostics."""

    names: List[str]
    x: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    iterations: int
    condition_number: float
    solver: str
    outliers: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    #: By which criterion the solver stopped (the fit is refused when it did not converge).
    converged_by: str = ""
    #: Stated doubts that do not refuse the fit (e.g. a residual far above the budget's reading uncertainty).
    warnings: list = field(default_factory=list)
    #: The user's own decision variables (added to ``prog``), by name: their solved values.
    extra: dict = field(default_factory=dict)


class LeastSquaresProgram:
    """min ½ Σ r_k(x)² over named parameters, on a Drake MathematicalProgram.

    Subclasses call :meth:`_declare` with the parameter names, set :attr:`x0`
    (the start), add their gauge to :attr:`prog`, and implement
    :meth:`residuals` and :meth:`reading_label`.
    """

    #: Appended to a rank-deficiency error: what the user can change.
    rank_hint = "fix a parameter or add readings"
    #: Appended to an error about parameters no reading touches.
    untouched_hint = "add readings that depend on them"

    def _declare(self, names, options: SolverOptions):
        from pydrake.solvers import MathematicalProgram
        from pydrake.symbolic import Variable

        self.options = options
        self.names = list(names)
        self.prog = MathematicalProgram()
        self.variables = np.array([Variable(n) for n in self.names])
        self.prog.AddDecisionVariables(self.variables)
        self.notes: List[str] = []
        self._cost_weights = None  # IRLS weights of the data cost (None: all 1)
        self.data_cost = self.prog.AddCost(self._data_cost_value, self.variables)
        self.data_cost.evaluator().set_description("data: 1/2 sum of squared residuals (mm^2)")
        self._set_solver_tolerances()

    def _set_solver_tolerances(self):
        """Tolerances on :attr:`prog` so that the solver Drake picks (SNOPT) stops at the least-squares minimum to
        the precision of LM (1e-6 mm / deg and below): SNOPT's default optimality tolerance (1e-6) stops ~1e-5 mm
        short of it with constraints. Users may override them with their own ``SetSolverOption``."""
        from pydrake.solvers import SnoptSolver

        # IPOPT keeps its defaults: in Drake it runs an L-BFGS Hessian that does not reach tighter ones.
        self.prog.SetSolverOption(SnoptSolver.id(), "Major optimality tolerance", NLP_OPTIMALITY_TOLERANCE)

    @property
    def x0(self) -> np.ndarray:
        """The start of the solvers (model units); setting it also sets the program's initial guess."""
        return self._x0

    @x0.setter
    def x0(self, value):
        self._x0 = np.asarray(value, dtype=float)
        self.prog.SetInitialGuess(self.variables, self._x0)

    def _data_cost_value(self, z):
        """½ Σ w_k r_k(x)² for floats; for AutoDiffXd the same value with gradient Jᵀ(w r) chained with z's."""
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        ad = z.dtype == object
        r, J = self.residuals(ExtractValue(z).ravel() if ad else np.asarray(z, dtype=float))
        w = np.ones_like(r) if self._cost_weights is None else self._cost_weights
        f = 0.5 * float(np.sum(w * r * r))
        return AutoDiffXd(f, (J.T @ (w * r)) @ ExtractGradient(z)) if ad else f

    @property
    def n_all(self) -> int:
        """Decision variables of :attr:`prog`: the model's parameters first, then the user's own."""
        return self.prog.num_vars()

    def _extra_values(self, z) -> dict:
        extra = self.prog.decision_variables()[len(self.names):]
        return {v.get_name(): float(z[self.prog.FindDecisionVariableIndex(v)]) for v in extra}

    def _start(self) -> np.ndarray:
        """The start over all decision variables: x0, then the user's initial guesses (0 where none is set)."""
        z = np.asarray(self.prog.initial_guess(), dtype=float).copy()
        z[:len(self.names)] = self.x0
        return np.where(np.isfinite(z), z, 0.0)

    def _pad(self, J):
        """The Jacobian over all decision variables (the user's own enter no residual)."""
        extra = self.n_all - J.shape[1]
        return sp.hstack([J, sp.csr_matrix((J.shape[0], extra))], format="csr") if extra else J

    def residuals(self, x):
        """(r (K,), sparse dr/dx (K, n)) at x."""
        raise NotImplementedError

    def reading_label(self, k: int) -> dict:
        """What identifies reading k to the user (e.g. its file line)."""
        return {"row": int(k)}

    def beam_lengths(self, x) -> np.ndarray:
        """Length of the laser beam of every reading at x, mm (for the budget's cosine error)."""
        raise NotImplementedError

    def layout(self, v) -> dict:
        """A parameter-shaped vector (e.g. uncertainties) in the model's result keys and shapes."""
        raise NotImplementedError

    def implausible(self, x) -> list:
        """Physically impossible values of a solution x, one phrase each (empty: plausible). Model-specific."""
        return []

    def default_budget(self):
        """The budget whose reading uncertainty the residual is compared with when the options name none."""
        return None

    @property
    def source(self) -> str:
        return getattr(getattr(self, "data", None), "source", "") or "campaign"

    def _equality_rows(self):
        """(A, b) of every linear equality in the program (gauge, fixed values), over all variables."""
        from pydrake.solvers import BoundingBoxConstraint, LinearConstraint

        rows, rhs = [], []
        for b in self.prog.GetAllConstraints():
            e = b.evaluator()
            if not isinstance(e, (LinearConstraint, BoundingBoxConstraint)):
                continue
            A = e.GetDenseA()
            eq = e.lower_bound() == e.upper_bound()
            idx = self.prog.FindDecisionVariableIndices(b.variables())
            full = np.zeros((int(eq.sum()), self.n_all))
            full[:, idx] = A[eq]
            rows.append(full)
            rhs.append(e.lower_bound()[eq])
        if not rows:
            return np.zeros((0, self.n_all)), np.zeros(0)
        return np.vstack(rows), np.concatenate(rhs)

    def reduced_hessian(self, H):
        """Column-scaled H restricted to the null space of the equality constraints (over all decision
        variables: an H over the model's parameters only is padded with zeros for the user's own)."""
        n = self.n_all
        if H.shape[0] < n:
            H = np.pad(H, ((0, n - H.shape[0]), (0, n - H.shape[0])))
        scale = np.sqrt(np.diag(H))
        A, _ = self._equality_rows()
        s = np.where(scale > 0, scale, 1.0)
        N = _null_space(A / s) if A.size else np.eye(len(s))
        return N.T @ (H / np.outer(s, s)) @ N, N, s

    def check_identifiability(self, x=None) -> float:
        """Raise :class:`UnidentifiableError` naming what the readings cannot determine; return cond.

        Checks the Jacobian at ``x`` (default the start): parameters no reading
        touches, then rank and conditioning within the constraints.
        """
        x = self.x0 if x is None else x
        r, J = self.residuals(x)
        self._checked = (x, r, J)  # the solver starts from the same point: reuse the evaluation
        H = _normal_matrix(self._pad(J), np.ones(J.shape[0])) + self._prior_hessian()  # priors determine too
        # The user's own variables need no reading: their constraints tie them (the rank check below sees it).
        untouched = [self.names[i] for i in np.flatnonzero(np.diag(H)[:len(self.names)] == 0)]
        if untouched:
            raise UnidentifiableError(f"not identifiable: {_listing(untouched)} -- no valid reading touches "
                                      f"{'it' if len(untouched) == 1 else 'them'} ({self.untouched_hint})",
                                      untouched)
        M, N, s = self.reduced_hessian(H)
        lam = np.linalg.eigvalsh(M)
        names = _weak_names(self._all_names(), M, N, s)
        if names:
            weak = int(np.sum(lam < RANK_TOLERANCE * lam[-1]))
            raise UnidentifiableError(f"not identifiable: {_listing(names)} -- a combination of them leaves every "
                                      f"reading unchanged (rank deficient by {weak}; {self.rank_hint})", names)
        return float(np.sqrt(lam[-1] / lam[0]))

    def _all_names(self) -> list:
        return self.names + [v.get_name() for v in self.prog.decision_variables()[len(self.names):]]

    def _regularize(self, error: UnidentifiableError):
        """Weak prior on the named parameters (1e-6 of a typical reading's weight)."""
        names = [n for n in error.names if n in self.names]
        if not names:
            raise error
        idx = [self.names.index(n) for n in names]
        w = 1e-6 * len(self._checked[1])  # a millionth of the readings' weight
        self.prog.AddQuadraticCost(w * np.eye(len(idx)), -w * self.x0[idx], self.variables[idx], is_convex=True)
        self.notes.append(f"regularized (weak prior to the start value): {_listing(names)}")

    # -- solve -------------------------------------------------------------------------------
    def fit(self) -> "Fit":
        """Check identifiability, solve (LM or NLP), estimate uncertainty, flag outliers."""
        o = self.options
        if o.solver not in ("lm", "nlp"):
            raise InputError(f"solver must be 'lm' or 'nlp', got {o.solver!r}")
        if o.loss not in ("l2", "huber"):
            raise InputError(f"loss must be 'l2' or 'huber', got {o.loss!r}")
        if o.solver == "lm":
            self.check_lm_program()
        # Small dense algebra: BLAS threads cost more than they give (measured 5.7 -> 4.4 ms at paper scale).
        with single_thread_blas() if len(self.names) <= SMALL_PROBLEM else contextlib.nullcontext():
            fit = self._fit()
        self.accept(fit)
        fit.warnings.extend(self.residual_warnings(fit))
        return fit

    # -- acceptance: refuse what is not to be trusted, state what is doubtful ---------------------
    def accept(self, fit: "Fit") -> None:
        """Raise :class:`FitRefused` (one line) unless the fit converged, its covariance is finite and
        positive definite within the gauge, and :meth:`implausible` finds nothing."""
        where = f"{self.source}: refused, nothing written --"
        if not fit.converged_by:
            raise FitRefused(f"{where} the solver did not converge: {self._stop_text()} after {fit.iterations} "
                             f"iterations (residual RMS {1e3 * _rms(fit.residuals):.4g} um); check the units "
                             f"(mm), the nominal values and the start")
        bad = [self.names[i] for i in np.flatnonzero(~np.isfinite(fit.x) | ~np.isfinite(fit.std))]
        if bad:
            raise FitRefused(f"{where} non-finite estimate or uncertainty of {_listing(bad)}")
        if self._weak:
            raise FitRefused(f"{where} the covariance is singular within the gauge (condition number "
                             f"{fit.condition_number:.3g}): {_listing(self._weak)} not determined by the readings "
                             f"at the solution")
        problems = self.implausible(fit.x)
        if problems:
            raise FitRefused(f"{where} physically impossible solution: {'; '.join(problems)}")

    def _user_costs(self):
        """The program's costs other than the data cost (which the solvers evaluate themselves)."""
        return [b for b in self.prog.GetAllCosts() if b.evaluator() is not self.data_cost.evaluator()]

    def check_lm_program(self) -> None:
        """LM steps take linear constraints and linear/quadratic costs only: name anything else, one line."""
        from pydrake.solvers import BoundingBoxConstraint, LinearConstraint, LinearCost, QuadraticCost

        bad = [b for b in self.prog.GetAllConstraints()
               if not isinstance(b.evaluator(), (LinearConstraint, BoundingBoxConstraint))]
        bad += [b for b in self._user_costs() if not isinstance(b.evaluator(), (LinearCost, QuadraticCost))]
        if bad:
            e = bad[0].evaluator()
            what = f"{type(e).__name__} {e.get_description()!r}" if e.get_description() else type(e).__name__
            raise InputError(f"the 'lm' solver takes linear constraints and linear/quadratic costs only; the "
                             f"program has a nonlinear {what} on {', '.join(v.get_name() for v in bad[0].variables())}"
                             f": use solver='nlp' (or pydrake.solvers.Solve(prog))")

    def _stop_text(self) -> str:
        stop = getattr(self, "_stop", None)
        return f"iteration cap {self.options.max_iterations} reached" if stop is None else stop[1]

    def residual_warnings(self, fit: "Fit") -> list:
        """A warning when the residual RMS exceeds :data:`RESIDUAL_WARNING_RATIO` times the reading
        uncertainty the budget predicts (RMS over the readings, at each reading's beam length), mm."""

        budget = self.options.budget if self.options.budget is not None else self.default_budget()
        if budget is None or not len(fit.residuals):
            return []
        u = _rms(ReadingErrors(budget).std(self.beam_lengths(fit.x)))
        rms = _rms(fit.residuals)
        ratio = rms / max(u, 1e-300)
        self.residual_ratio = (float(ratio), float(u), getattr(budget, "name", ""))
        if ratio <= RESIDUAL_WARNING_RATIO:
            return []
        return [f"residual RMS {1e3 * rms:.2f} um is {ratio:.1f} x the reading uncertainty {1e3 * u:.2f} um that "
                f"the budget '{budget.name}' predicts (warning above {RESIDUAL_WARNING_RATIO:g} x): a model error "
                f"(e.g. a map too coarse), a budget that does not fit the instrument, or readings in other units"]

    def _fit(self) -> "Fit":
        o = self.options
        for _ in range(len(self.names)):
            try:
                self.check_identifiability()
                break
            except UnidentifiableError as e:
                if not o.regularize:
                    raise
                self._regularize(e)
        self._solver_used = "lm: Levenberg-Marquardt, steps solved by Drake"
        x, iterations, weights = self._solve_lm() if o.solver == "lm" else self._solve_nlp()
        return self._finish(x, iterations, weights)

    def _weights(self, r):
        if self.options.loss == "l2":
            return np.ones_like(r)
        sigma = _robust_sigma(r)
        a = np.abs(r) / (self.options.huber_k * sigma)
        return np.where(a <= 1, 1.0, 1.0 / np.maximum(a, 1e-300))

    def _user_cost(self, x) -> float:
        return float(sum(self.prog.EvalBinding(b, x)[0] for b in self._user_costs()))

    def _solve_lm(self):
        """LM over all decision variables (x = the model's parameters, then the user's own)."""
        n = len(self.names)
        x = self._feasible(self._start())
        checked = getattr(self, "_checked", None)
        r, J = checked[1:] if checked is not None and np.array_equal(checked[0], x[:n]) else self.residuals(x[:n])
        J = self._pad(J)
        lam, steps = 1e-6, 0
        self._stop = None  # None after the loop: the iteration cap ended it
        for _ in range(self.options.max_iterations):
            w = self._weights(r)
            H = _normal_matrix(J, w)
            g = J.T @ (w * r)
            cost = 0.5 * np.sum(w * r * r) + self._user_cost(x)
            # Quadratic user costs carry no constant term, so the cost may be negative: tolerances on |cost|.
            tol = 1e-12 * abs(cost)
            while True:
                # The user's own variables carry no curvature of the data: damp them by the mean one.
                D = np.diag(H).copy()
                D[D == 0] = np.mean(D[D > 0]) if (D > 0).any() else 1.0
                delta = self._step(x, H + lam * np.diag(D), g)
                x_new = x + delta
                r_new, J_new = self.residuals(x_new[:n])
                J_new = self._pad(J_new)
                cost_new = 0.5 * np.sum(w * r_new * r_new) + self._user_cost(x_new)
                # What the quadratic model promised: below rounding level, we are at the minimum.
                predicted = -(g @ delta + 0.5 * delta @ (H @ delta))
                if cost_new <= cost or predicted <= tol or lam > 1e12:
                    break
                lam *= 8.0
            if cost_new > cost:
                # No step lowers the cost: at the minimum if the quadratic model promised nothing more.
                at_minimum = predicted <= tol + 1e-300
                self._stop = (True, "the predicted cost decrease is below 1e-12 of the cost") if at_minimum else (
                    False, f"no step lowers the cost (damping {lam:.0e}) though the model predicts "
                           f"{predicted / max(abs(cost), 1e-300):.1e} of it")
                break
            x, r, J, steps = x_new, r_new, J_new, steps + 1
            lam = max(lam / 4.0, 1e-9)
            if cost - cost_new <= tol:
                self._stop = (True, "the relative cost decrease of the last step is below 1e-12")
                break
        self._final = (x, r, J)
        return x, steps, self._weights(r)

    def _feasible(self, x):
        """x moved onto the program's constraints by the least change (mm, deg) when it violates them -- e.g.
        a user variable tied to parameters, or a bound the start lies outside; LM's steps then keep it feasible
        (from an infeasible point a step that must also restore feasibility may raise the cost, and LM would
        stop there)."""
        constraints = self.prog.GetAllConstraints()
        if not constraints or self.prog.CheckSatisfied(constraints, x, 1e-9):
            return x
        return x + self._step(x, np.eye(len(x)), np.zeros(len(x)))

    def _step(self, x, Hd, g):
        """Solve the LM step program: min ½δᵀHdδ + gᵀδ + user costs, s.t. the program's constraints at x + δ."""
        from pydrake.solvers import MathematicalProgram, Solve

        step = MathematicalProgram()
        d = step.NewContinuousVariables(len(x), "delta")
        step.AddQuadraticCost(Hd, g, d, is_convex=True)
        _shift_bindings(self.prog, step, d, x, skip=self.data_cost.evaluator())
        result = Solve(step)
        if not result.is_success():
            # EqConstrainedQP can refuse a nearly singular KKT system at the optimum: retry interior-point.
            from pydrake.solvers import ClarabelSolver
            result = ClarabelSolver().Solve(step)
        if not result.is_success():
            raise InputError(f"the constraints added to the program cannot be satisfied "
                             f"({result.get_solver_id().name()}: {result.get_solution_result()})")
        return result.GetSolution(d)

    def _solve_nlp(self):
        """The program itself (data cost, user variables, constraints, costs) by the solver Drake picks;
        Huber loss: three IRLS rounds re-weighting the data cost."""
        from pydrake.solvers import Solve, SolutionResult

        z = self._start()
        all_vars = self.prog.decision_variables()
        rounds = 3 if self.options.loss == "huber" else 1
        self._cost_weights = np.ones(len(self.residuals(self.x0)[0]))
        try:
            for _ in range(rounds):  # IRLS: re-weight, re-solve
                result = Solve(self.prog, z)
                if result.get_solution_result() == SolutionResult.kSolverSpecificError:
                    result = self._resolve_at_default_tolerance(result, all_vars)
                if not result.is_success():
                    raise InputError(f"NLP solver {result.get_solver_id().name()} failed: "
                                     f"{result.get_solution_result()}")
                z = result.GetSolution(all_vars)
                self._cost_weights = self._weights(self.residuals(z[:len(self.names)])[0])
            weights = self._cost_weights
        finally:
            self._cost_weights = None  # prog's data cost is the plain least squares again
        self._solver_used = f"nlp: {result.get_solver_id().name()}"
        self._stop = (True, f"{result.get_solver_id().name()} reports {result.get_solution_result().name}")
        return z, rounds, weights

    def _resolve_at_default_tolerance(self, result, all_vars):
        """SNOPT may end "cannot improve the current point" (info 41) at the tight optimality tolerance of
        :meth:`_set_solver_tolerances`, depending on the BLAS kernels (seen with OPENBLAS_CORETYPE=Sandybridge
        on a constrained problem): re-solve once from that point at SNOPT's default tolerance (1e-6), whose
        success is then SNOPT's own verdict; any other failure stays a failure."""
        from pydrake.solvers import SnoptSolver, Solve, SolverOptions as DrakeSolverOptions

        if result.get_solver_id() != SnoptSolver.id():
            return result
        options = DrakeSolverOptions()
        options.SetOption(SnoptSolver.id(), "Major optimality tolerance", 1e-6)
        retry = Solve(self.prog, result.GetSolution(all_vars), options)
        if retry.is_success():
            self.notes.append("SNOPT could not improve its point at the tight optimality tolerance; re-solved "
                              "from it at its default tolerance (1e-6)")
        return retry

    def quadratic_costs(self):
        """(Q, b) of the program's quadratic costs ½xᵀQx + bᵀx (priors, regularization), all variables."""
        from pydrake.solvers import QuadraticCost

        Q, q = np.zeros((self.n_all, self.n_all)), np.zeros(self.n_all)
        for b in self._user_costs():
            if isinstance(b.evaluator(), QuadraticCost):
                idx = self.prog.FindDecisionVariableIndices(b.variables())
                Q[np.ix_(idx, idx)] += b.evaluator().Q()
                q[idx] += b.evaluator().b()
        return Q, q

    def _prior_hessian(self) -> np.ndarray:
        return self.quadratic_costs()[0]

    def _finish(self, z, iterations, weights) -> "Fit":
        n = len(self.names)
        final = getattr(self, "_final", None)
        r, J = final[1:] if final is not None and final[0] is z else self.residuals(z[:n])
        J = self._pad(J)
        H = _normal_matrix(J, weights)
        M_data, N, s = self.reduced_hessian(H)
        lam = np.linalg.eigvalsh(M_data)
        cond = float(np.sqrt(lam[-1] / lam[0])) if lam[0] > RANK_TOLERANCE * lam[-1] else float("inf")
        self._stop = getattr(self, "_stop", (True, "solved"))
        # Priors (user costs, regularization) inform the estimate: include them in the covariance.
        prior = self._prior_hessian()
        if prior.any():
            M, N, s = self.reduced_hessian(H + prior)
        else:
            M = M_data
        self._weak = _weak_names(self._all_names(), M, N, s)  # what the covariance (with priors) cannot determine
        dof = max(len(r) - N.shape[1], 1)
        sigma2 = np.sum(weights * r * r) / dof
        cov = (N / s[:, None]) @ np.linalg.solve(M, (N / s[:, None]).T) * sigma2
        zr = r / _robust_sigma(r)
        out = [dict(self.reading_label(k), residual_mm=float(r[k]), normalized=float(zr[k]))
               for k in np.argsort(-np.abs(zr)) if abs(zr[k]) > self.options.outlier_threshold]
        stop = self._stop
        cov_x = cov[:n, :n]
        return Fit(list(self.names), z[:n], np.sqrt(np.maximum(np.diag(cov_x), 0)), cov_x, r, iterations, cond,
                   f"{self._solver_used} ({self.options.loss} loss)", out, list(self.notes),
                   stop[1] if stop is not None and stop[0] else "", extra=self._extra_values(z))


# -- helpers -------------------------------------------------------------------------------------
def _shift_bindings(src, dst, d, x, skip=None):
    """Copy src's linear constraints and linear/quadratic costs to dst in the step δ = e − x
    (all but the cost ``skip``: the data cost, which the step's Gauss-Newton model replaces)."""
    from pydrake.solvers import LinearConstraint, BoundingBoxConstraint, LinearCost, QuadraticCost

    for b in src.GetAllConstraints():
        e = b.evaluator()
        idx = src.FindDecisionVariableIndices(b.variables())
        if not isinstance(e, (LinearConstraint, BoundingBoxConstraint)):
            raise InputError(f"constraint {type(e).__name__} is not linear: use the 'nlp' solver")
        A = e.GetDenseA()
        shift = A @ x[idx]
        lo, hi = e.lower_bound() - shift, e.upper_bound() - shift
        eq = e.lower_bound() == e.upper_bound()
        # Equalities stay equalities, so Drake can pick its exact EqConstrainedQP solver.
        if eq.any():
            dst.AddLinearEqualityConstraint(A[eq], lo[eq], d[idx])
        if (~eq).any():
            dst.AddLinearConstraint(A[~eq], lo[~eq], hi[~eq], d[idx])
    for b in src.GetAllCosts():
        e = b.evaluator()
        if e is skip:
            continue
        idx = src.FindDecisionVariableIndices(b.variables())
        if isinstance(e, QuadraticCost):
            dst.AddQuadraticCost(e.Q(), e.Q() @ x[idx] + e.b(), d[idx], is_convex=True)
        elif isinstance(e, LinearCost):
            dst.AddLinearCost(e.a(), 0.0, d[idx])
        else:
            raise InputError(f"cost {type(e).__name__} is not linear or quadratic: use the 'nlp' solver")


def _normal_matrix(J, w) -> np.ndarray:
    """Dense JᵀWJ; through a dense J when it is narrow (sparse products cost more there)."""
    if J.shape[1] <= SMALL_PROBLEM:
        Jd = J.toarray()
        return Jd.T @ (w[:, None] * Jd)
    return (J.T @ sp.diags(w) @ J).toarray()


def _weak_names(names, M, N, s) -> list:
    """Parameters in the near-null space of the reduced (scaled, within the constraints) normal matrix M."""
    if not np.all(np.isfinite(M)):
        return list(names)
    lam, vec = np.linalg.eigh(M)
    weak = lam < RANK_TOLERANCE * lam[-1]
    if not weak.any():
        return []
    mag = np.max(np.abs(N @ vec[:, np.flatnonzero(weak)]), axis=1)
    return [names[i] for i in np.flatnonzero(mag > 0.1 * mag.max())]


def _rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v)))) if len(v) else 0.0


def _null_space(A, rtol=1e-12):
    u, s, vt = np.linalg.svd(A)
    rank = int(np.sum(s > rtol * max(s.max(), 1e-300)))
    return vt[rank:].T


def _robust_sigma(r) -> float:
    """1.4826 × median absolute deviation: the residual scale, blind to a few gross outliers."""
    s = 1.4826 * np.median(np.abs(r - np.median(r)))
    return float(s) if s > 0 else float(np.sqrt(np.mean(r * r)) + 1e-300)


def _listing(names, most=8) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")

