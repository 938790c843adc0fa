"""Identification of the SCARA models of paper 000 §3 as a Drake MathematicalProgram.

* D-H model (Eq. 3-5): e = [L1, L2, θ20, P_1..P_Nt, d0_1..d0_Nt].
* Error-map model (Eq. 6-10): e = [L1, L2, Δθ1,map(·, ±1), Δθ2,map(·, ±1), P, d0]
  (θ20 absorbed in the J2 map).

Both minimize Σ (‖p̂(k) − P_j‖ − d0_j − d_j(k))² (Eq. 5 / Eq. 10) with the
residuals and analytic Jacobians of :mod:`olti_drake.kinematics`.

:attr:`Identifier.prog` holds one named decision variable per parameter
(``L1_mm``, ``J2_reverse_deg[3]``, ``P0_x_mm``, ``d0_0_mm``, ...) and the gauge
constraint. Add your own constraints and costs to it before :meth:`Identifier.solve`.
Two solvers:

* ``lm`` (default): Levenberg-Marquardt; every step is a MathematicalProgram in
  the step δ -- the Gauss-Newton quadratic model plus the program's linear
  constraints and linear/quadratic costs shifted to δ -- solved by the solver
  Drake chooses (EqConstrainedQP for equality constraints only). Working in δ
  keeps full precision however large the parameters are.
* ``nlp``: the whole program with the least-squares cost (analytic gradient)
  handed to Drake's NLP solver (SNOPT/IPOPT); also takes nonlinear user
  constraints.

Units: mm and degrees in every parameter, residual and Jacobian.
"""

import contextlib
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import scipy.sparse as sp

from .campaign_io import CampaignData
from .csvio import InputError
from .errormap import ErrorMap
from .kinematics import PAPER_L1_MM, PAPER_L2_MM, ScaraModel, rows_to_csr
from .threads import single_thread_blas

#: Relative eigenvalue below which a parameter combination counts as unidentifiable.
RANK_TOLERANCE = 1e-12
#: Up to this many unknowns the dense algebra runs on one BLAS thread.
SMALL_PROBLEM = 300


class UnidentifiableError(InputError):
    """The campaign cannot determine the named parameters (listed in :attr:`names`)."""

    def __init__(self, message: str, names=()):
        super().__init__(message)
        self.names = list(names)


@dataclass
class IdentificationOptions:
    """How to identify (units mm, deg).

    ``grid1_deg``/``grid2_deg``: map nodes (default: distinct commanded angles).
    ``reflectors_mm``: initial reflector positions (e.g. from the Eq. (2)
    search); ``fix_reflectors`` makes them known (then N_t = 2 suffices).
    ``loss``: ``l2`` or ``huber`` (IRLS, threshold ``huber_k`` robust sigmas).
    ``regularize``: instead of stopping on unidentifiable parameters, add a
    weak prior pulling them to their initial value (and say so).
    """

    model: str = "errormap"
    grid1_deg: Optional[np.ndarray] = None
    grid2_deg: Optional[np.ndarray] = None
    nominal_L1_mm: float = PAPER_L1_MM
    nominal_L2_mm: float = PAPER_L2_MM
    reflectors_mm: Optional[np.ndarray] = None
    fix_reflectors: bool = False
    loss: str = "l2"
    huber_k: float = 3.0
    outlier_threshold: float = 4.0
    regularize: bool = False
    solver: str = "lm"
    max_iterations: int = 100


@dataclass
class Identification:
    """The identified model, its uncertainty (k = 1, linear propagation) and diagnostics."""

    model: ScaraModel
    reflectors_mm: np.ndarray
    dead_paths_mm: np.ndarray
    names: List[str]
    x: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    residuals_mm: np.ndarray
    iterations: int
    condition_number: float
    gauge: str
    solver: str
    outliers: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    n_readings: int = 0

    @property
    def residual_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_mm ** 2)))

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def uncertainty(self, name: str) -> float:
        return float(self.std[self.names.index(name)])


def parse_grid(text: str, name: str) -> np.ndarray:
    """``start:stop:step`` (inclusive) or a comma list, degrees, e.g. ``-140:60:10``."""
    try:
        if ":" in text:
            a, b, s = (float(v) for v in text.split(":"))
            if not s > 0 or b < a:
                raise ValueError
            n = int(round((b - a) / s))
            if abs(a + n * s - b) > 1e-9 * max(1.0, abs(b)):
                raise InputError(f"{name}: step {s:g} does not divide [{a:g}, {b:g}]")
            return a + s * np.arange(n + 1)
        g = np.array([float(v) for v in text.split(",")])
    except InputError:
        raise
    except ValueError:
        raise InputError(f"{name}: expected START:STOP:STEP (degrees, STOP >= START, STEP > 0) "
                         f"or a comma list, got {text!r}") from None
    if g.size == 0 or np.any(np.diff(g) <= 0) or not np.all(np.isfinite(g)):
        raise InputError(f"{name}: grid must be finite and strictly ascending, got {text!r}")
    return g


def _reflector_fit(p, d, P0=None):
    """(P, d0) of one reflector from positions p (K, 2) and readings d (K,), mm.

    Without a start: the linearized multilateration ‖p‖² − 2p·P + ‖P‖² =
    (d + d0)² is linear in (P, d0, ‖P‖² − d0²); then Gauss-Newton on Eq. (5).
    """
    if P0 is None:
        A = np.column_stack([-2 * p, -2 * d, np.ones(len(d))])
        sol, *_ = np.linalg.lstsq(A, d ** 2 - np.sum(p ** 2, axis=1), rcond=None)
        P, d0 = sol[:2], sol[2]
    else:
        P = np.asarray(P0, dtype=float)
        d0 = np.mean(np.hypot(*(p - P).T) - d)
    for _ in range(20):
        diff = p - P
        dist = np.hypot(*diff.T)
        r = dist - d0 - d
        J = np.column_stack([-diff / dist[:, None], -np.ones(len(d))])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        P, d0 = P + step[:2], d0 + step[2]
        if np.max(np.abs(step)) < 1e-12:
            break
    return P, d0


class Identifier:
    """The identification problem of 000 §3 for one campaign and model.

    Build it, optionally add constraints/costs to :attr:`prog` (its decision
    variables are :attr:`variables`, named as :attr:`names`), then call
    :meth:`solve`.
    """

    def __init__(self, data: CampaignData, options: IdentificationOptions = None):
        from pydrake.solvers import MathematicalProgram
        from pydrake.symbolic import Variable

        self.data, self.options = data, options or IdentificationOptions()
        o = self.options
        if o.model not in ("dh", "errormap"):
            raise InputError(f"model must be 'dh' or 'errormap', got {o.model!r}")
        self._check_reflectors()
        self.robot0 = self._robot_start()
        self.n_t = data.n_reflectors
        self.n_robot = len(self.robot0.parameter_names())
        self.names = (self.robot0.parameter_names() + [f"P{j}_{c}_mm" for j in range(self.n_t) for c in "xy"]
                      + [f"d0_{j}_mm" for j in range(self.n_t)])
        self.prog = MathematicalProgram()
        self.variables = np.array([Variable(n) for n in self.names])
        self.prog.AddDecisionVariables(self.variables)
        self.x0 = self._initial_guess()
        self.gauge = self._add_gauge()
        if o.fix_reflectors:
            idx = slice(self.n_robot, self.n_robot + 2 * self.n_t)
            self.prog.AddBoundingBoxConstraint(self.x0[idx], self.x0[idx], self.variables[idx])
        self.notes: List[str] = []

    # -- model -------------------------------------------------------------------------------
    def _check_reflectors(self):
        o, d = self.options, self.data
        counts = np.bincount(d.reflector)
        if counts.size < 3 and not o.fix_reflectors:
            raise UnidentifiableError(
                f"{d.source}: {counts.size} reflector position(s); with unknown reflector positions at least 3 "
                f"are needed (000 §3.2.2 Remark 1) -- P and d0 of every reflector are not identifiable")
        few = np.flatnonzero(counts < 3)
        if few.size:
            raise UnidentifiableError(
                f"{d.source}: reflector {few[0]} has {counts[few[0]]} valid reading(s); each reflector needs at "
                f"least 3 (its position P{few[0]} and dead path d0_{few[0]} are 3 unknowns)",
                [f"P{few[0]}_x_mm", f"P{few[0]}_y_mm", f"d0_{few[0]}_mm"])

    def _robot_start(self) -> ScaraModel:
        o, c = self.options, self.data.commands
        if o.model == "dh":
            return ScaraModel(o.nominal_L1_mm, o.nominal_L2_mm, 0.0)
        maps = []
        for axis, grid, cmd in (("J1", o.grid1_deg, c.theta1_deg), ("J2", o.grid2_deg, c.theta2_deg)):
            # Distinct commanded angles; files written elsewhere may carry 1e-12 deg of float noise.
            g = np.unique(np.round(cmd, 9)) if grid is None else np.asarray(grid, dtype=float)
            out = (cmd < g[0] - 1e-9) | (cmd > g[-1] + 1e-9)
            if out.any():
                k = np.flatnonzero(out)[0]
                raise InputError(f"{self.data.source}:{self.data.line[k]}: {axis} command {cmd[k]:g} deg is outside "
                                 f"the {axis} map grid [{g[0]:g}, {g[-1]:g}] deg")
            maps.append(ErrorMap(g, np.zeros(g.size), np.zeros(g.size), axis=axis))
        return ScaraModel(o.nominal_L1_mm, o.nominal_L2_mm, None, *maps)

    def split(self, x):
        """Parameter vector -> (ScaraModel, reflectors (Nt, 2) mm, dead paths (Nt,) mm)."""
        n = self.n_robot
        return (self.robot0.with_parameters(x[:n]), x[n:n + 2 * self.n_t].reshape(-1, 2), x[n + 2 * self.n_t:])

    def residual_rows(self, X, displacement_mm=None):
        """Eq. (10) residuals of T parameter vectors at once, Jacobian row-compressed.

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`).
            displacement_mm: readings (K,) or per trial (T, K); default the campaign's.

        Returns:
            r (T, K) mm; cols (K, m) parameter indices shared by all trials;
            vals (T, K, m) the matching dr/dx entries: the robot's few non-zeros
            (kinematics), −u on P_j, −1 on d0_j, u the unit vector from P_j to p̂(k).
        """
        X = np.atleast_2d(X)
        n, n_t, j = self.n_robot, self.n_t, self.data.reflector
        p, cols, dx, dy = self.robot0.jacobian_rows(self.data.commands, X[:, :n])
        P = X[:, n:n + 2 * n_t].reshape(len(X), n_t, 2)
        diff = p - P[:, j]
        dist = np.hypot(diff[..., 0], diff[..., 1])
        u = diff / dist[..., None]
        d = self.data.displacement_mm if displacement_mm is None else displacement_mm
        r = dist - X[:, n + 2 * n_t:][:, j] - d
        cols = np.column_stack([cols, n + 2 * j, n + 2 * j + 1, n + 2 * n_t + j])
        vals = np.concatenate([u[..., :1] * dx + u[..., 1:] * dy, -u, -np.ones(r.shape + (1,))], axis=-1)
        return r, cols, vals

    def residuals(self, x):
        """Eq. (10) residuals r_k = ‖p̂(k) − P_j‖ − d0_j − d_j(k) (mm) and the sparse dr/dx."""
        r, cols, vals = self.residual_rows(np.asarray(x)[None])
        return r[0], rows_to_csr(cols, vals[0], len(self.names))

    # -- start and gauge -----------------------------------------------------------------------
    def _initial_guess(self) -> np.ndarray:
        """Nominal robot, reflectors/dead paths fitted per reflector on the nominal model."""
        o = self.options
        p = self.robot0.positions(self.data.commands)
        P0 = None if o.reflectors_mm is None else np.asarray(o.reflectors_mm, dtype=float).reshape(-1, 2)
        if P0 is not None and len(P0) != self.n_t:
            raise InputError(f"reflectors_mm gives {len(P0)} positions but the campaign has {self.n_t} reflectors")
        fits = [_reflector_fit(p[self.data.reflector == j], self.data.displacement_mm[self.data.reflector == j],
                               None if P0 is None else P0[j]) for j in range(self.n_t)]
        P = np.array([f[0] for f in fits]) if P0 is None or not o.fix_reflectors else P0
        d0 = np.array([f[1] for f in fits])
        return np.concatenate([self.robot0.parameter_vector(), P.ravel(), d0])

    def _add_gauge(self) -> str:
        if self.options.model == "dh":
            return ("none needed: the D-H model has no J1 offset, so X lies along the arm at theta1* = 0 "
                    "(formats.md frame)")
        if self.options.fix_reflectors:
            return "fixed by the known reflector positions (no free rotation about J1)"
        m = self.robot0.map1
        at = float(np.clip(0.0, m.grid_deg[0], m.grid_deg[-1]))
        w = (m.weights([at, at], [1.0, -1.0]).toarray().sum(axis=0) / 2)[None, :]
        self.prog.AddLinearEqualityConstraint(w, [0.0], self.variables[2:2 + 2 * m.n_nodes]).evaluator(
        ).set_description("gauge")
        return (f"rotation about J1 fixed by the constraint (dtheta1({at:g} deg, +1) + dtheta1({at:g} deg, -1))/2 = 0: "
                f"X lies along the arm at theta1* = {at:g} deg, mean of both approach directions")

    # -- linear algebra shared by the solvers and the uncertainty ----------------------------
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
            full = np.zeros((int(eq.sum()), len(self.names)))
            full[:, idx] = A[eq]
            rows.append(full)
            rhs.append(e.lower_bound()[eq])
        if not rows:
            return np.zeros((0, len(self.names))), np.zeros(0)
        return np.vstack(rows), np.concatenate(rhs)

    def reduced_hessian(self, H):
        """Column-scaled H restricted to the null space of the equality constraints."""
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
        H = _normal_matrix(J, np.ones(J.shape[0])) + self._prior_hessian()  # priors determine what they constrain
        untouched = [self.names[i] for i in np.flatnonzero(np.diag(H) == 0)]
        if untouched:
            raise UnidentifiableError(f"not identifiable: {_listing(untouched)} -- no valid reading touches "
                                      f"{'it' if len(untouched) == 1 else 'them'} (set a coarser map grid)",
                                      untouched)
        M, N, s = self.reduced_hessian(H)
        lam, vec = np.linalg.eigh(M)
        weak = lam < RANK_TOLERANCE * lam[-1]
        if weak.any():
            v = (N @ vec[:, np.flatnonzero(weak)]) / s[:, None]
            mag = np.max(np.abs(v * s[:, None]), axis=1)
            names = [self.names[i] for i in np.flatnonzero(mag > 0.1 * mag.max())]
            raise UnidentifiableError(f"not identifiable: {_listing(names)} -- a combination of them leaves every "
                                      f"reading unchanged (rank deficient by {int(weak.sum())}; check the "
                                      f"reflector layout, e.g. collinear reflectors, or fix a parameter)", names)
        return float(np.sqrt(lam[-1] / lam[0]))

    def _regularize(self, error: UnidentifiableError):
        """Weak prior on the named parameters (1e-6 of a typical reading's weight)."""
        names = error.names
        idx = [self.names.index(n) for n in names]
        w = 1e-6 * len(self.data)
        self.prog.AddQuadraticCost(w * np.eye(len(idx)), -w * self.x0[idx], self.variables[idx], is_convex=True)
        self.notes.append(f"regularized (weak prior to the start value): {_listing(names)}")

    # -- solve -------------------------------------------------------------------------------
    def solve(self) -> Identification:
        """Check identifiability, solve (LM or NLP), estimate uncertainty, flag outliers."""
        o = self.options
        if o.solver not in ("lm", "nlp"):
            raise InputError(f"solver must be 'lm' or 'nlp', got {o.solver!r}")
        if o.loss not in ("l2", "huber"):
            raise InputError(f"loss must be 'l2' or 'huber', got {o.loss!r}")
        # Small dense algebra: BLAS threads cost more than they give (measured 5.7 -> 4.4 ms at paper scale).
        with single_thread_blas() if len(self.names) <= SMALL_PROBLEM else contextlib.nullcontext():
            return self._solve()

    def _solve(self) -> Identification:
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
        return self._result(x, iterations, weights)

    def _weights(self, r):
        if self.options.loss == "l2":
            return np.ones_like(r)
        sigma = _robust_sigma(r)
        a = np.abs(r) / (self.options.huber_k * sigma)
        return np.where(a <= 1, 1.0, 1.0 / np.maximum(a, 1e-300))

    def _user_cost(self, x) -> float:
        return float(sum(self.prog.EvalBinding(b, x)[0] for b in self.prog.GetAllCosts()))

    def _solve_lm(self):
        x = self.x0.copy()
        checked = getattr(self, "_checked", None)
        r, J = checked[1:] if checked is not None and np.array_equal(checked[0], x) else self.residuals(x)
        lam, steps = 1e-6, 0
        for _ in range(self.options.max_iterations):
            w = self._weights(r)
            H = _normal_matrix(J, w)
            g = J.T @ (w * r)
            cost = 0.5 * np.sum(w * r * r) + self._user_cost(x)
            while True:
                delta = self._step(x, H + lam * np.diag(np.diag(H)), g)
                x_new = x + delta
                r_new, J_new = self.residuals(x_new)
                cost_new = 0.5 * np.sum(w * r_new * r_new) + self._user_cost(x_new)
                # What the quadratic model promised: below rounding level, we are at the minimum.
                predicted = -(g @ delta + 0.5 * delta @ (H @ delta))
                if cost_new <= cost or predicted <= 1e-12 * cost or lam > 1e12:
                    break
                lam *= 8.0
            if cost_new > cost:
                break
            x, r, J, steps = x_new, r_new, J_new, steps + 1
            lam = max(lam / 4.0, 1e-9)
            if cost - cost_new <= 1e-12 * cost:
                break
        self._final = (x, r, J)
        return x, steps, self._weights(r)

    def _step(self, x, Hd, g):
        """Solve the LM step program: min ½δᵀHdδ + gᵀδ + user costs, s.t. the program's constraints at x + δ."""
        from pydrake.solvers import MathematicalProgram, Solve

        step = MathematicalProgram()
        d = step.NewContinuousVariables(len(x), "delta")
        step.AddQuadraticCost(Hd, g, d, is_convex=True)
        _shift_bindings(self.prog, step, d, x)
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
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue
        from pydrake.solvers import Solve

        prog = self.prog.Clone()
        weights = np.ones(len(self.data))

        def cost(z):
            v = ExtractValue(z).ravel() if z.dtype == object else z
            r, J = self.residuals(v)
            f = 0.5 * np.sum(weights * r * r)
            if z.dtype != object:
                return f
            return AutoDiffXd(f, (J.T @ (weights * r)) @ ExtractGradient(z))

        prog.AddCost(cost, self.variables)
        x = self.x0.copy()
        rounds = 3 if self.options.loss == "huber" else 1
        for _ in range(rounds):  # IRLS: re-weight, re-solve
            prog.SetInitialGuess(self.variables, x)
            result = Solve(prog)
            if not result.is_success():
                raise InputError(f"NLP solver {result.get_solver_id().name()} failed: {result.get_solution_result()}")
            x = result.GetSolution(self.variables)
            weights[:] = self._weights(self.residuals(x)[0])
        self._solver_used = f"nlp: {result.get_solver_id().name()}"
        return x, rounds, weights

    def quadratic_costs(self):
        """(Q, b) of the program's quadratic costs ½xᵀQx + bᵀx (priors, regularization), all variables."""
        from pydrake.solvers import QuadraticCost

        Q, q = np.zeros((len(self.names), len(self.names))), np.zeros(len(self.names))
        for b in self.prog.GetAllCosts():
            if isinstance(b.evaluator(), QuadraticCost):
                idx = self.prog.FindDecisionVariableIndices(b.variables())
                Q[np.ix_(idx, idx)] += b.evaluator().Q()
                q[idx] += b.evaluator().b()
        return Q, q

    def _prior_hessian(self) -> np.ndarray:
        return self.quadratic_costs()[0]

    def _result(self, x, iterations, weights) -> Identification:
        final = getattr(self, "_final", None)
        r, J = final[1:] if final is not None and final[0] is x else self.residuals(x)
        H = _normal_matrix(J, weights)
        M_data, N, s = self.reduced_hessian(H)
        lam = np.linalg.eigvalsh(M_data)
        cond = float(np.sqrt(lam[-1] / lam[0])) if lam[0] > RANK_TOLERANCE * lam[-1] else float("inf")
        # Priors (user costs, regularization) inform the estimate: include them in the covariance.
        prior = self._prior_hessian()
        M = M_data if not prior.any() else None
        if M is None:
            M, N, s = self.reduced_hessian(H + prior)
        dof = max(len(r) - N.shape[1], 1)
        sigma2 = np.sum(weights * r * r) / dof
        cov = (N / s[:, None]) @ np.linalg.solve(M, (N / s[:, None]).T) * sigma2
        model, P, d0 = self.split(x)
        z = r / _robust_sigma(r)
        out = [{"line": int(self.data.line[k]), "reflector": int(self.data.reflector[k]),
                "residual_mm": float(r[k]), "normalized": float(z[k])}
               for k in np.argsort(-np.abs(z)) if abs(z[k]) > self.options.outlier_threshold]
        return Identification(model, P, d0, list(self.names), x, np.sqrt(np.maximum(np.diag(cov), 0)), cov, r,
                              iterations, cond, self.gauge,
                              f"{self._solver_used} ({self.options.loss} loss)", out, list(self.notes), len(r))


def identify(data: CampaignData, options: IdentificationOptions = None) -> Identification:
    """Identify the model of ``options.model`` from the campaign (000 Eq. 5 or Eq. 10)."""
    return Identifier(data, options).solve()


# -- helpers -------------------------------------------------------------------------------------
def _shift_bindings(src, dst, d, x):
    """Copy src's linear constraints and linear/quadratic costs to dst in the step δ = e − x."""
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

