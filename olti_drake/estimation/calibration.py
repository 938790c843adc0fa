"""One calibration program: a position model, a measurement, a gauge, solver options.

Paper 000 Eq. (5)/(10) (a SCARA reflector P_j with dead path d0_j) and paper 001 Eq. (3) (a machine-tool
station P_j with dead path L0_j) read the same thing: d = ‖p − P_j‖ − d0_j, mm.

* :func:`station_fit`: (P_j, d0_j) from points p taken as known (nominal kinematics, or commands) -- the
  start of the SCARA identification and of the multilateration.
* :class:`Calibration`: the least-squares program (:class:`~olti_drake.estimation.calibration.LeastSquaresProgram`:
  data cost on ``prog``, identifiability, robust loss, covariance, acceptance; Monte Carlo and linear
  propagation in :mod:`olti_drake.estimation.uncertainty`) over any *measurement* object that offers
  ``names``, ``start_vector()``, ``residuals(x) -> (r, sparse dr/dx)``, ``beam_lengths(x)`` and
  ``layout(v)`` -- e.g. :class:`olti_drake.model.serial.DistanceMeasurement` on an N-joint
  :class:`~olti_drake.model.serial.SerialPositionModel`, with the gauge of
  :func:`olti_drake.model.serial.find_gauge`; or :class:`olti_drake.model.measurements.StationDistanceMeasurement`
  on the free points of 001 (:class:`olti_drake.model.free_points.FreePoints`), with a named gauge of
  :mod:`olti_drake.model.gauges` -- the 2D/3D :class:`~olti_drake.estimation.multilateration.Multilateration`.
  The distance residual itself (:func:`distance_rows_nd`, batched for the Monte Carlo) lives in
  :mod:`olti_drake.model.measurements`. The SCARA :class:`~olti_drake.estimation.identification.Identifier` is
  the same measurement on the SCARA's closed form (:class:`olti_drake.model.scara.ScaraPositionModel`, 000 Eq. 3
  and 7) with its J1 gauge (:func:`olti_drake.model.gauges.scara_gauge`).

The least-squares program every calibration is (:class:`LeastSquaresProgram` below): Nonlinear least squares on a Drake MathematicalProgram -- the solver machinery the models share.

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

All the algebra within the constraints (rank, condition number, covariance, and
the LM steps of large problems) is one factorization, :class:`Within`: dense
eigen-decomposition up to :data:`LARGE_PROBLEM` decision variables; above it a
Householder null space of the constraints, a Cholesky factor of the reduced
normal matrix, Lanczos for its extreme eigenvalues, the standard uncertainties
from the factor (the full covariance only when read), and LM steps by conjugate
gradients preconditioned by the identifiability check's factor -- no n³
eigen-decomposition or n × n products, so ~4 000 unknowns identify in seconds.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List

import numpy as np
import scipy.sparse as sp
from scipy.linalg import lapack

from olti_drake.errors import InputError
from olti_drake.model.budget import ReadingErrors
from olti_drake.model.measurements import lengths
from olti_drake.threads import (blas_threads, in_parallel, single_thread_blas, symmetric_times, triangular_inverse,
                                triangular_solve)


#: Relative eigenvalue below which a parameter combination counts as unidentifiable.
RANK_TOLERANCE = 1e-12
#: Up to this many unknowns the normal matrix is formed through a dense J.
SMALL_PROBLEM = 300
#: Above this many decision variables the algebra within the constraints is factorized (:class:`Within`, large
#: path: Cholesky, Lanczos, no eigen-decomposition) and LM steps are conjugate gradients preconditioned by it.
LARGE_PROBLEM = 500
#: Relative accuracy of the extreme eigenvalues (condition number, rank) on the large path (Lanczos).
LANCZOS_TOLERANCE = 1e-7
#: Up to this dimension the large path's extreme eigenvalues come from the dense eigen-decomposition.
DENSE_EXTREMES = 100
#: Above this many decision variables (the large path: a second factorization and its Lanczos cost more than
#: the metric change's few block products) the identifiability check's rank and variance work runs in a thread
#: beside LM (its BLAS/LAPACK calls release the GIL), and the covariance reuses the check's factorization when
#: the normal matrix at the solution differs from the start's by at most :data:`REUSE_TOLERANCE` in its metric
#: -- every variance is then within that factor of the solution's.
REUSE_ABOVE = LARGE_PROBLEM
REUSE_TOLERANCE = 0.02
#: Thousands of unknowns: the variances come from U⁻¹ computed in single precision (half the time of double)
#: when sampled rows agree with double precision to :data:`INVERSE_RTOL`, else double; the check's Cholesky runs
#: on every BLAS thread (:func:`_factor_threads`).
THOUSANDS = 2000
INVERSE_RTOL = 1e-5
#: LM stops (above LARGE_PROBLEM variables) before a step that would change no parameter by more than this
#: fraction of its standard uncertainty (:meth:`LeastSquaresProgram._negligible_decrease`): the rest is far
#: below what the readings determine (scipy's least_squares stops at a relative cost change of 1e-8: about
#: 0.03 sigma at 10^5 readings).
STEP_FRACTION = 0.01
#: Longest lengthening of a step repeated in the same direction: 2^EXTRAPOLATIONS (LeastSquaresProgram._extrapolate).
EXTRAPOLATIONS = 10
#: Two consecutive LM steps in this cosine of each other (in the normal matrix's diagonal scaling) are one crawl.
PARALLEL_COSINE = 0.99
#: LM steps after which a geometric fall of the cost's decrease is read as linear convergence (:meth:`_crawl_done`),
#: and how many of the last decreases give its ratio.
CRAWL_AFTER, CRAWL_RATE_STEPS = 50, 10
#: Sparse products with J (JᵀWJ, the metric change) on two threads from this many non-zeros of J: the SCARA's
#: 1 deg grid (9·10⁴) took 1.4x as long on two threads as on one, the six-axis 5 deg campaign (7.6·10⁵) 0.62x.
PARALLEL_NONZEROS = 250_000
#: :meth:`Within.metric_change` stops when a Krylov block raises its estimate by less than this fraction.
METRIC_SETTLED = 0.01
HELPER_THREAD = "olti-within"  # the name of Within.start_background's thread
#: Optimality tolerance set on the program for the NLP solvers (SNOPT, IPOPT), relative.
NLP_OPTIMALITY_TOLERANCE = 1e-8  # 1e-10: SNOPT ends "cannot be improved" (info 41), a failure, at the minimum
#: SNOPT's major-iteration limit set on the program (its own default, 1000, stops short on six-axis maps).
NLP_MAJOR_ITERATIONS = 5000
#: A residual RMS above this multiple of the reading uncertainty the budget predicts is a stated warning.
RESIDUAL_WARNING_RATIO = 3.0
#: An l2 fit's reading beyond this many robust sigma (and this many budget reading u, when there is a budget)
#: is a gross outlier -- a blunder, not the model: its warning comes first and names the Huber loss.
GROSS_OUTLIER_SIGMA = 20.0
#: The losses of :attr:`SolverOptions.loss`: least squares, the robust ones (IRLS, :meth:`LeastSquaresProgram._weights`;
#: scale c = k x the robust sigma, k = ``huber_k``), and ``auto`` (:meth:`LeastSquaresProgram._auto_loss_fit`).
ROBUST_LOSSES = ("huber", "soft_l1", "cauchy")
LOSSES = ("l2",) + ROBUST_LOSSES + ("auto",)
#: Huber's usual k (95 % efficiency at Gaussian readings): the k of the Huber refit that ``loss='auto'`` makes.
AUTO_HUBER_K = 1.345
#: ``loss='auto'``: an l2 fit whose residual RMS exceeds this multiple of its robust sigma (1.4826 MAD) has a heavy
#: tail (Gaussian residuals: 1.0; Laplace: 1.38; clean six-axis campaigns, truths outside the model family: 1.0-1.23
#: measured; 8 % of the readings in a 2.5-8.7 mm dead-path jump over ~0.7 mm of resolution noise and model error:
#: 2.1-2.4, tests/estimation/test_real_data.py) -- outliers, besides the gross ones (:data:`GROSS_OUTLIER_SIGMA`).
HEAVY_TAIL_RATIO = 1.5
#: The iteration cap that fits the problem's size (:class:`SizeCap`, the default of
#: :attr:`SolverOptions.max_iterations`): max(100, this many per unknown), at most :data:`MAX_SIZE_CAP`. Measured: a
#: six-axis ``dh`` program (31 unknowns) from the nominal start takes 3-28 LM iterations on synthetic single-anchor
#: campaigns (tests/estimation/test_real_data.py, l2, Huber, with and without priors); issue 23 reports 126 on its real
#: single-anchor draw-wire data with a weak prior (~4 per unknown), 441-1734 without (towards implausible values).
ITERATIONS_PER_UNKNOWN = 10
MAX_SIZE_CAP = 2000
#: A refused fit that did not converge names this many of the parameters that kept moving over the last
#: :data:`MOVING_STEPS` LM steps (their change over their standard uncertainty at the start).
MOVING_NAMED, MOVING_STEPS = 4, 5


class SizeCap(int):
    """The default iteration cap (an int, 100): LM then runs up to max(100, :data:`ITERATIONS_PER_UNKNOWN` x the
    unknowns) iterations, at most :data:`MAX_SIZE_CAP` (:meth:`LeastSquaresProgram.iteration_cap`). A plain int
    given as ``max_iterations`` (``--max-iterations N``) is the cap itself."""

    def cap(self, unknowns: int) -> int:
        return int(max(int(self), min(ITERATIONS_PER_UNKNOWN * int(unknowns), MAX_SIZE_CAP)))


#: The description of the smoothness prior's cost on a program (results, propagation and the scaled program find
#: it by it).
SMOOTHNESS_PRIOR = "smoothness prior: roughness of the maps (second differences)"
#: LM stops (and the acceptance refuses the fit by name) when every this many iterations the parameters are still
#: physically impossible (:meth:`LeastSquaresProgram.implausible`): a fit that far off leads nowhere, and the
#: size-fitted cap would otherwise let a doomed fit run for thousands of iterations.
OUT_OF_BOUNDS_AFTER = 50
#: The default of :attr:`SolverOptions.max_iterations`.
SIZE_CAP = SizeCap(100)


class UnidentifiableError(InputError):
    """The campaign cannot determine the named parameters (listed in :attr:`names`)."""

    def __init__(self, message: str, names=()):
        super().__init__(message)
        self.names = list(names)


class FitRefused(InputError):
    """The solution is not one to trust -- not converged, singular or non-finite covariance, or physically
    impossible parameters. Raised before anything is written; the message is one line."""


class VagueSolution(UnidentifiableError, FitRefused):
    """A solution whose named parameters have a u beyond what is physically plausible
    (:meth:`LeastSquaresProgram.plausible_u`): refused, and unidentifiable -- a prior (``regularize``) helps."""


@dataclass
class SolverOptions:
    """How to solve, for every model.

    ``loss``: ``l2``; ``huber``, ``soft_l1`` or ``cauchy`` (IRLS, scale ``huber_k`` robust sigmas: the k of every
    robust loss); or ``auto``: l2 unless its residuals show outliers (gross ones, or a heavy tail), then Huber at
    k = :data:`AUTO_HUBER_K`, said in a note naming the outlying lines (:meth:`LeastSquaresProgram._auto_loss_fit`).
    ``max_iterations``: LM's cap; the default (:data:`SIZE_CAP`) fits the problem's size.
    ``outlier_threshold``: report readings whose normalized residual exceeds it.
    ``regularize``: instead of stopping on unidentifiable parameters, add a
    weak prior pulling them to their initial value (and say so).
    ``solver``: ``lm`` or ``nlp``.
    ``smoothing``: the roughness prior of a map model (:meth:`LeastSquaresProgram.roughness`; issue 23):
    ``"off"``, ``"auto"`` (its weight by restricted maximum likelihood, :mod:`olti_drake.estimation.smoothing`)
    or a weight λ ≥ 0 (the cost ½ λ ‖R x‖² beside ½ Σ w r², mm² per (deg/deg²)²·deg), or a result's statement
    ``{"weight": λ, "group_weights": {group: λ_g}}`` given again to reproduce it (the maps' own roughness in its
    u: :meth:`LeastSquaresProgram.roughness_groups`).
    """

    loss: str = "l2"
    huber_k: float = 3.0
    outlier_threshold: float = 4.0
    regularize: bool = False
    solver: str = "lm"
    max_iterations: int = SIZE_CAP
    #: Budget whose predicted reading uncertainty the residual RMS is checked against (None: the model's default).
    budget: object = None
    smoothing: object = "off"


def _weight_ok(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value >= 0


def _statement_ok(value) -> bool:
    """A result's smoothing statement: {"weight": λ, "group_weights": {group: λ_g} (optional)}."""
    if not isinstance(value, dict) or not _weight_ok(value.get("weight")):
        return False
    groups = value.get("group_weights") or {}
    return isinstance(groups, dict) and all(_weight_ok(v) for v in groups.values())


def smoothing_on(options) -> bool:
    """Whether ``options`` ask for the smoothness prior (:attr:`SolverOptions.smoothing` 'auto' or a weight)."""
    setting = getattr(options, "smoothing", "off")
    return not (setting is None or (isinstance(setting, str) and setting == "off"))


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
    #: The smoothness prior of a map model, as stated in the result: method (how the weight was chosen, or
    #: "given"), weight, score
    #: (−2 log restricted likelihood), effective parameters, readings, rounds; None without one.
    smoothing: dict = None
    #: The residual variance σ² (mm², weighted) that scales the covariance (NaN: no covariance).
    sigma2: float = float("nan")
    #: The model's own error (mm, k = 1) that every prediction shares: the residuals' σ beyond the readings' u
    #: (:meth:`LeastSquaresProgram.lack_of_fit`); a predicted point's or reading's u adds it in quadrature.
    lack_of_fit_mm: float = 0.0
    #: The under-resolution check of a map model (:func:`olti_drake.estimation.resolution.resolution_check`: the
    #: result's ``resolution_check``); None when none ran.
    resolution: dict = None


def suspect_readings_line(outliers, limit: int = 10) -> str:
    """A summary's line of a fit's suspect readings (:attr:`Fit.outliers`, each by its file line, and its coordinate
    for a point reading) and their normalized residual: "" when there are none."""
    if not outliers:
        return ""
    shown = ", ".join(f"line {o['line']}" + (f" {o['coordinate']}" if "coordinate" in o else "")
                      + f" ({o['normalized']:+.1f} sigma)" for o in outliers[:limit])
    more = f" and {len(outliers) - limit} more" if len(outliers) > limit else ""
    return f"  {len(outliers)} suspect reading(s) beyond the outlier threshold: {shown}{more}"


def _covariance_get(fit):
    """Fit.covariance: large problems form the (n, n) matrix from the factorization on first use only."""
    cov = fit.__dict__["_covariance"]
    if callable(cov):
        cov = fit.__dict__["_covariance"] = cov()
    return cov


def _covariance_set(fit, value):
    fit.__dict__["_covariance"] = value


def lazy_covariance(cls):
    """Class decorator for a dataclass with a ``covariance`` field: Cls(..., covariance, ...) and obj.covariance = C
    still work; a callable given as the covariance is evaluated (once) when the covariance is first read."""
    cls.covariance = property(_covariance_get, _covariance_set)
    return cls


def deferred_covariance(fit):
    """The fit's covariance as it was given: the matrix, or the callable that forms it when read -- for a result
    built from the fit that keeps it deferred (:func:`lazy_covariance`)."""
    return fit.__dict__["_covariance"]


lazy_covariance(Fit)


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
        self._uncertainty = True  # fit(uncertainty=...): False for a solution-only fit
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
        # SNOPT's default limit (1000 major iterations) ends a six-axis error-map problem (hundreds of unknowns in
        # mm and deg) before its minimum: its quasi-Newton Hessian needs a few thousand steps there.
        self.prog.SetSolverOption(SnoptSolver.id(), "Major iterations limit", NLP_MAJOR_ITERATIONS)
        self.prog.SetSolverOption(SnoptSolver.id(), "Iterations limit", 100 * NLP_MAJOR_ITERATIONS)

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

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        """Length of the laser beam of every reading at x, mm (for the budget's cosine error). ``residuals``: the
        residuals at x when at hand (a distance residual is beam − dead path − reading: no evaluation then)."""
        raise NotImplementedError

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (values, or with ``uncertainty`` standard uncertainties: what is not a
        parameter, e.g. a curve's values, is then left to the covariance) in the model's result keys and shapes."""
        raise NotImplementedError

    def implausible(self, x) -> list:
        """Physically impossible values of a solution x, one phrase each (empty: plausible). Model-specific."""
        return []

    def default_budget(self):
        """The budget whose reading uncertainty the residual is compared with when the options name none."""
        return None

    def roughness(self):
        """Roughness rows R (sparse, over :attr:`names`) of the model's maps for the smoothness prior ½ λ ‖R x‖²
        (:attr:`SolverOptions.smoothing`), or None: the model has no map."""
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

    def check_identifiability(self, x=None, defer: bool = False):
        """Raise :class:`UnidentifiableError` naming what the readings cannot determine; return cond.

        Checks the Jacobian at ``x`` (default the start): parameters no reading
        touches, then rank and conditioning within the constraints. ``defer`` (large problems, from
        :meth:`fit`): when the Cholesky factorization succeeds, the rank and condition (Lanczos) and the
        variances are computed in a thread beside the solver, and :meth:`_confirm_identifiable` raises the same
        error after it (before anything is accepted); returns None then.
        """
        x = self.x0 if x is None else x
        r, J = self.residuals(x)
        self._checked = (x, r, J)  # the solver starts from the same point: reuse the evaluation
        H = self._normal(self._pad(J), np.ones(J.shape[0]))
        prior = self._prior_hessian()
        if prior is not None:  # priors determine too
            H = H + prior
        # The user's own variables need no reading: their constraints tie them (the rank check below sees it).
        untouched = [self.names[i] for i in np.flatnonzero(np.diag(H)[:len(self.names)] == 0)]
        if untouched:
            raise self._explain(UnidentifiableError(
                f"not identifiable: {_listing(untouched)} -- no valid reading touches "
                f"{'it' if len(untouched) == 1 else 'them'} ({self.untouched_hint})", untouched))
        within = self.within(H, overwrite=True)
        self._within0 = within  # the large path's LM steps are preconditioned by it
        self._deferred = defer and within.large and within.factorized
        if self._deferred:
            within.start_background()
            return None
        self._raise_if_weak(within)
        low, top = within.extremes()
        return float(np.sqrt(top / low))

    def _raise_if_weak(self, within: "Within") -> None:
        names = within.weak_names(self._all_names())
        if names:
            self._within0 = None
            lam = within._eigh()[0]
            weak = int(np.sum(lam < RANK_TOLERANCE * lam[-1]))
            raise self._explain(UnidentifiableError(
                f"not identifiable: {_listing(names)} -- a combination of them leaves every reading unchanged "
                f"(rank deficient by {weak}; {self.rank_hint})", names))

    def _explain(self, error: UnidentifiableError) -> UnidentifiableError:
        """Hook: a model may add where in the campaign the named parameters' readings are."""
        return error

    #: Appended to an error about parameters whose u at the start would exceed physical plausibility.
    vague_hint = "add readings that determine them, or fix them"

    def plausible_u(self):
        """Hook: the largest physically plausible standard uncertainty of every parameter (:attr:`names`, model
        units; inf: no bound), or None (no such check: the default). A parameter whose u at the start -- the
        identifiability check's factorization times the reading variance (:meth:`reading_sigma`) -- would exceed
        it is not identifiable (:meth:`_raise_if_vague`), though the rank is full."""
        return None

    def reading_sigma(self):
        """(u mm, what it is) of one reading, to weigh priors and to judge u before solving: the RMS reading u of
        the budget (``options.budget``, else :meth:`default_budget`) at the start's beam lengths; without a budget
        the robust sigma (1.4826 MAD) of the residuals of the least-squares fit linearized at the start (one
        Gauss-Newton step: by the identifiability check's factorization when at hand, else the minimum-norm step
        by LSQR on the column-scaled Jacobian; the gauge changes no residual), times √(m / (m − n)) for the n
        unknowns it fits -- robust, so a block of outliers does not inflate it. Computed once per program."""
        cached = getattr(self, "_reading_sigma", None)
        if cached is not None:
            return cached
        budget = self.options.budget if self.options.budget is not None else self.default_budget()
        if budget is not None:
            u = _rms(ReadingErrors(budget).std(self.beam_lengths(self.x0)))
            out = (float(u), f"the reading uncertainty of the budget '{getattr(budget, 'name', '')}'")
        else:
            checked = getattr(self, "_checked", None)
            at_start = checked is not None and np.array_equal(checked[0], self.x0)
            r, J = checked[1:] if at_start else self.residuals(self.x0)
            J = sp.csr_matrix(J)
            norms = np.sqrt(np.asarray(J.multiply(J).sum(axis=0)).ravel())
            within = getattr(self, "_within0", None)
            if at_start and within is not None and (not within.large or within.factorized):
                # The identifiability check's factorization at the start: the Gauss-Newton step within the
                # program's constraints (gauge, ties), exactly.
                g = self._pad(J).T @ np.asarray(r, float)
                step = within.to_full(within.solve(within.to_null(-g / within.s))) / within.s
                lin = r + J @ step[:J.shape[1]]
            else:  # (rank deficient: no factorization) the minimum-norm step by LSQR, column-scaled
                from scipy.sparse.linalg import lsqr

                s = np.where(norms > 0, norms, 1.0)
                y = lsqr(J @ sp.diags(1.0 / s), -np.asarray(r, float), atol=1e-10, btol=1e-10,
                         iter_lim=min(max(200, 2 * J.shape[1]), 2000))[0]
                lin = r + J @ (y / s)
            m, k = len(r), int(np.sum(norms > 0))
            if m - k < max(10, 0.1 * m):
                # Hardly more readings than unknowns: the linearized fit runs through them (its residuals are
                # rounding), so they tell no reading uncertainty -- take a stated one.
                out = (UNKNOWN_READING_MM, f"stated: the readings ({m}) barely exceed the unknowns they fit ({k}), "
                                           f"so their residuals tell no reading uncertainty")
            else:
                u = _robust_sigma(lin) * np.sqrt(m / max(m - k, 1)) if m else 0.0
                out = (float(u), "the robust sigma of the residuals of the least-squares fit linearized at the "
                                 "start")
        self._reading_sigma = out
        return out

    #: Judge u before solving (:meth:`_raise_if_vague`); a model may turn it off for a second try, leaving the
    #: judgment to the solution's u (:meth:`accept`).
    vague_at_start = True

    def _raise_if_vague(self) -> None:
        """Raise :class:`UnidentifiableError` naming the parameters whose u at the start (the identifiability
        check's factorization, priors included, times :meth:`reading_sigma` squared) exceeds :meth:`plausible_u`,
        each with its u; parameters with a prior already are not named again."""
        within = getattr(self, "_within0", None)
        if not self.vague_at_start or within is None or self.plausible_u() is None:
            return
        sigma, what = self.reading_sigma()
        u = np.sqrt(np.maximum(within.inverse_diagonal()[:len(self.names)], 0.0)) * sigma
        error = self._vague_error(u, f"u at the start, readings of u {1e3 * sigma:.3g} um: {what}",
                                  UnidentifiableError)
        if error is not None:
            raise self._explain(error)

    def _vague_error(self, u, basis: str, cls):
        """``cls`` (an :class:`UnidentifiableError`) naming the parameters whose u (``u``, model units) exceeds
        :meth:`plausible_u` -- not those with a prior already --, their u in ``u_at_start``; None when none does."""
        bounds = self.plausible_u()
        if bounds is None:
            return None
        n = len(self.names)
        bounds = np.asarray(bounds, float)
        u = np.asarray(u, float)[:n]
        prior = self._prior_hessian()
        held = np.diag(prior)[:n] > 0 if prior is not None else np.zeros(n, bool)
        idx = np.flatnonzero((u > bounds) & ~held)
        if not idx.size:
            return None
        idx = idx[np.argsort(-(u[idx] / bounds[idx]))]

        def unit(name):
            return "deg" if "_deg" in name else "mm"
        shown = ", ".join(f"{self.names[i]} (u {u[i]:.3g} {unit(self.names[i])}, bound {bounds[i]:g})"
                          for i in idx[:8]) + (f" and {len(idx) - 8} more" if len(idx) > 8 else "")
        error = cls(f"not identifiable: {shown} -- the readings would determine {'it' if len(idx) == 1 else 'them'} "
                    f"only to a standard uncertainty beyond what the physical part can have ({basis}; "
                    f"{self.vague_hint})", [self.names[i] for i in idx])
        error.u_at_start = {self.names[i]: float(u[i]) for i in idx}  # (vague, not rank deficient)
        return error

    def _confirm_identifiable(self, wait: bool = True) -> None:
        """The deferred part of :meth:`check_identifiability`: raise its error once the thread has decided
        (``wait`` False: only if it already has -- polled by LM, so a deficient problem stops early)."""
        within = getattr(self, "_within0", None)
        if not getattr(self, "_deferred", False) or within is None or not (wait or within.extremes_ready()):
            return
        self._deferred = False
        self._raise_if_weak(within)

    def _normal(self, J, w) -> np.ndarray:
        """JᵀWJ dense; small problems keep the last one: the identifiability check's is LM's first, LM's last
        is the covariance's (the same J object and weights). Large problems overwrite it: not kept."""
        kept = getattr(self, "_normal_kept", None)
        if kept is not None and kept[0] is J and np.array_equal(kept[1], w):
            return kept[2]
        H = _normal_matrix(J, w)
        self._normal_kept = (J, w.copy(), H) if not self._large() else None
        return H

    def within(self, H, overwrite: bool = False) -> "Within":
        """H (over the model's parameters or all decision variables) within the program's linear equalities,
        factorized (:class:`Within`; large path above :data:`LARGE_PROBLEM` variables; ``overwrite``: H may
        serve as its work space)."""
        n = self.n_all
        if H.shape[0] < n:
            H = np.pad(H, ((0, n - H.shape[0]), (0, n - H.shape[0])))
        return Within(H, self._equality_rows()[0], large=self._large(), overwrite=overwrite)

    def _large(self) -> bool:
        """The large path: above :data:`LARGE_PROBLEM` variables, or a fit without uncertainty (:meth:`fit`) --
        its identifiability check needs the rank only, not the reference eigen-decomposition, and its solution
        no more than the readings determine (:meth:`_negligible_decrease`)."""
        return self.n_all > LARGE_PROBLEM or not self._uncertainty

    def _all_names(self) -> list:
        if self.n_all == len(self.names):
            return list(self.names)
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
    def fit(self, uncertainty: bool = True) -> "Fit":
        """Check identifiability, solve (LM or NLP), estimate uncertainty, flag outliers.

        ``uncertainty`` False: the solution only -- no covariance at it (std NaN, covariance None, condition
        number that of the check), for a fit of which only x is used (e.g. a loop of cross-validation fits): the
        identifiability check (rank by the large path, :meth:`_large`) and convergence are still required; LM
        stops where no parameter would move by :data:`STEP_FRACTION` of its u."""
        self._uncertainty = uncertainty
        o = self.options
        if o.solver not in ("lm", "nlp"):
            raise InputError(f"solver must be 'lm' or 'nlp', got {o.solver!r}")
        if o.loss not in LOSSES:
            raise InputError(f"loss must be {', '.join(repr(v) for v in LOSSES[:-1])} or 'auto', got {o.loss!r}")
        if isinstance(o.max_iterations, bool) or not (isinstance(o.max_iterations, (int, np.integer))
                                                      and o.max_iterations >= 1):
            raise InputError(f"max_iterations must be a whole number >= 1, got {o.max_iterations!r}")
        if o.solver == "lm":
            self.check_lm_program()
        fit = self._auto_loss_fit() if o.loss == "auto" else self._accepted_fit()
        if uncertainty:  # (the residual's warning compares it with the budget: for a result, not a solution only)
            fit.warnings.extend(self.gross_outlier_warnings(fit))
            fit.warnings.extend(self.residual_warnings(fit))
        return fit

    def _accepted_fit(self) -> "Fit":
        """The solve (with the smoothness prior when asked for) and :meth:`accept`."""
        # One BLAS thread at every size: small algebra gains nothing from threads (5.7 -> 4.4 ms at paper scale),
        # and on a shared machine their spin-waiting made a Cholesky of 866 unknowns 7.2 s instead of 0.05 s;
        # results then also do not depend on the thread count.
        with single_thread_blas():
            fit = self._smoothed_fit() if self.smoothing_rows() is not None else self._fit()
        self.accept(fit)
        return fit

    def _auto_loss_fit(self) -> "Fit":
        """``loss='auto'``: the l2 fit, returned as it is (a note saying so) unless its residuals -- or, when it is
        refused, those of its last iterate -- show outliers: a gross one (:meth:`gross_outliers`) or a heavy tail
        (RMS over the robust sigma above :data:`HEAVY_TAIL_RATIO`). Then the program is fitted again from its
        start with the Huber loss at k = :data:`AUTO_HUBER_K`, the note naming the outlying lines (beyond the
        outlier threshold of the l2 residuals). Every other option as given."""
        import types

        given = self.options
        try:
            self.options = dataclasses.replace(given, loss="l2")
            refused, fit = None, None
            self._final = None
            if getattr(self, "_given", None) is not None:  # a solution found elsewhere: no refit to choose
                fit = self._accepted_fit()
                fit.notes.append("loss auto: the solution was given (another solver's): judged as l2")
                return fit
            try:
                fit = self._accepted_fit()
                r, x = np.asarray(fit.residuals, float), fit.x
            except FitRefused as e:
                final = getattr(self, "_final", None)
                if final is None:
                    raise
                refused, x, r = e, final[0][:len(self.names)], np.asarray(final[1], float)
            if not r.size:
                if refused is not None:
                    raise refused
                return fit
            sigma = _robust_sigma(r)
            tail = _rms(r) / max(sigma, 1e-300)
            gross = self.gross_outliers(types.SimpleNamespace(residuals=r, x=x))
            if not gross and tail <= HEAVY_TAIL_RATIO:
                if refused is not None:
                    raise refused
                fit.notes.append(f"loss auto: l2 -- its residuals show no outliers (none beyond "
                                 f"{GROSS_OUTLIER_SIGMA:g} robust sigma; RMS {tail:.2f} x the robust sigma "
                                 f"{1e3 * sigma:.4g} um, at most {HEAVY_TAIL_RATIO:g})")
                return fit
            zr = r / sigma
            order = np.argsort(-np.abs(zr))
            out = [dict(self.reading_label(k), normalized=float(zr[k]))
                   for k in order[np.abs(zr[order]) > given.outlier_threshold]]
            self.options = dataclasses.replace(given, loss="huber", huber_k=AUTO_HUBER_K)
            self._final = None
            self._forget_chosen_smoothing()  # (chosen on the l2 fit, the weight saw the outliers as roughness)
            robust = self._accepted_fit()
            why = (f"{len(gross)} reading(s) beyond {GROSS_OUTLIER_SIGMA:g} robust sigma" if gross else
                   f"a heavy tail: RMS {tail:.2f} x the robust sigma {1e3 * sigma:.4g} um, above {HEAVY_TAIL_RATIO:g}")
            what = "did not converge" if refused is not None else "converged"
            robust.notes.append(
                f"loss auto: the l2 fit's residuals ({what}) show outliers ({why}); refitted with the Huber loss, "
                f"k = {AUTO_HUBER_K:g} robust sigma, which down-weights them: {len(out)} reading(s) beyond "
                f"{given.outlier_threshold:g} robust sigma of the l2 residuals: {_outlier_listing(out)}")
            return robust
        finally:
            self.options = given

    def smoothing_rows(self):
        """The roughness rows when :attr:`SolverOptions.smoothing` asks for the prior and the model has maps."""
        setting = getattr(self.options, "smoothing", "off")
        if not smoothing_on(self.options):
            return None
        if not (setting == "auto" or _weight_ok(setting) or _statement_ok(setting)):
            raise InputError(f"smoothing: 'auto', 'off' or a weight >= 0, got {setting!r}")
        R = self.roughness()
        return R if R is not None and R.shape[0] else None

    def roughness_groups(self):
        """The group label of each :meth:`roughness` row (each error motion's map: its own weight when the weight
        is chosen from the data), or None: one group."""
        return None

    def _smoothing_groups(self, R):
        """{group: its rows of R} when the model groups its roughness rows in more than one group, else None."""
        labels = self.roughness_groups()
        if labels is None or len(set(labels)) < 2:
            return None
        if len(labels) != R.shape[0]:
            raise RuntimeError(f"{len(labels)} roughness group labels for {R.shape[0]} rows")
        labels = np.asarray(labels, dtype=object)
        R = sp.csr_matrix(R)
        return {g: R[np.flatnonzero(labels == g)] for g in sorted(set(labels))}

    def _group_misfit(self, groups, weights: dict, lam: float):
        """D (n, n) = Σ_g λ (λ/λ_g − 1) R_gᵀR_g: what the maps' own roughness (prior variance σ²/λ_g of group g)
        adds to the normal matrix of the estimate made at the common weight λ -- its error covariance is
        σ² H⁻¹ (K + Σ_g λ²/λ_g P_g) H⁻¹ = σ² H⁻¹ + σ² H⁻¹ D H⁻¹ (H = K + λP). None when every λ_g is λ."""
        unknown, missing = sorted(set(weights) - set(groups or {})), sorted(set(groups or {}) - set(weights))
        if unknown or missing:
            raise InputError(f"smoothing: group weights for {', '.join(unknown) or 'no other'} group(s), none for "
                             f"{', '.join(missing) or 'none'} (the model's maps: {', '.join(groups or {}) or 'one'})")
        D = None
        for g, Rg in groups.items():
            k = lam * (lam / max(float(weights[g]), 1e-300) - 1.0)
            if k > 0:
                D = (0.0 if D is None else D) + k * np.asarray((Rg.T @ Rg).todense())
        return D

    #: Rounds of refit and likelihood scan until the chosen weight moves by less than a factor 10^0.1.
    SMOOTHING_ROUNDS = 4

    def smoothing_weight(self) -> dict:
        """The smoothness prior ½ λ ‖R x‖² of :attr:`SolverOptions.smoothing` on :attr:`prog` (issue 23), its weight
        λ given or chosen: by restricted maximum likelihood (:func:`olti_drake.estimation.smoothing.reml_scan`) at
        a solution, refitted there, in rounds until it settles (each fit a solution only, from the last one).
        Once per program: {"weight", "P" (RᵀR), "choice", "rounds", "x" (the last solution), "binding"}; the
        binding stays on :attr:`prog` (a solver given the program solves with the prior)."""
        state = getattr(self, "_smoothing", None)
        if state is not None:
            return state
        R = self.smoothing_rows()
        n = len(self.names)
        P = np.asarray((R.T @ R).todense())
        setting, uncertainty, x0 = self.options.smoothing, self._uncertainty, self.x0.copy()
        given = getattr(self, "_given", None)
        groups, per_group = self._smoothing_groups(R), None
        if setting == "auto":  # start at a weight the prior and the data share (c of the scan, 10^-3 of it)
            _, J = self.residuals(x0)
            lam = 1e-3 * float(np.sum(J.multiply(J))) / max(float(np.trace(P)), 1e-300)
        elif isinstance(setting, dict):
            lam = float(setting["weight"])
            per_group = {g: float(v) for g, v in (setting.get("group_weights") or {}).items()} or None
        else:
            lam = float(setting)
        binding = self._smoothing_binding(lam, P)
        choice, rounds, x = None, 0, x0
        options = self.options
        try:
            self._given, self._uncertainty = None, False
            if options.loss == "auto":  # (chosen on the l2 fit; a robust refit chooses again, with its weights)
                self.options = dataclasses.replace(options, loss="l2")
            for rounds in range(1, self.SMOOTHING_ROUNDS + 1):
                first = self._fit()
                self.accept(first)  # (a fit refused here is refused as it is: no more rounds)
                x = self.x0 = first.x
                z = np.concatenate([x, np.array(list(first.extra.values()), dtype=float)])
                choice = self._scan_smoothing(z, P, lam, given=setting != "auto")
                if setting != "auto" or abs(np.log10(max(choice.weight, 1e-300) / max(lam, 1e-300))) < 0.1:
                    break
                lam = choice.weight
                binding.evaluator().UpdateCoefficients(lam * P, np.zeros(n))
            if setting == "auto" and choice.weight != lam:  # (settled: the estimate is at lam, so is its tr A --
                # the u then equals that of the same weight given, as olti uncertainty re-adds it)
                at = self._scan_smoothing(z, P, lam, given=True)
                choice = dataclasses.replace(choice, effective_parameters=at.effective_parameters)
            if setting == "auto" and groups is not None:
                per_group = self._scan_group_weights(z, groups, lam, P).weights
        except Exception:
            self.prog.RemoveCost(binding)
            raise
        finally:
            self.x0, self._uncertainty, self._given, self.options = x0, uncertainty, given, options
        misfit = self._group_misfit(groups, per_group, lam) if per_group else None
        self._smoothing = {"weight": lam, "P": P, "choice": choice, "rounds": rounds, "x": x, "binding": binding,
                           "group_weights": per_group, "misfit": misfit}
        return self._smoothing

    def _scan_group_weights(self, z, groups, lam: float, P):
        """:func:`~olti_drake.estimation.smoothing.group_weights` on the linearization at the solution z
        (:meth:`_linearized`: the prior λP bound there taken out of the program's quadratic costs)."""
        from olti_drake.estimation import smoothing as sm

        lin = self._linearized(z, lam, P)
        extra = self.n_all - len(self.names)  # (the user's own variables: no roughness)
        R_groups = {k: sp.hstack([Rg, sp.csr_matrix((Rg.shape[0], extra))], format="csr") if extra else Rg
                    for k, Rg in groups.items()}
        return sm.group_weights(lin["H"], lin["other"], R_groups, lin["g"], z, lin["A"], lin["rss"], lin["m"], lam,
                                other0=lin["other0"], floor=self._smoothing_floor())

    def _forget_chosen_smoothing(self):
        """Drop a smoothness weight chosen by likelihood (its cost off :attr:`prog`), so that the next fit chooses
        it again: after ``loss='auto'`` turned robust, the l2 fit's outliers had made the maps look rough and the
        weight too large (a five-axis campaign with 2 % gross readings: λ 10 -> 1.6e4, unseen tool points 1.8x
        worse). A weight given by the user stays."""
        state = getattr(self, "_smoothing", None)
        if state is None or self.options.smoothing != "auto":
            return
        self.prog.RemoveCost(state["binding"])
        self._smoothing = None

    def _smoothing_binding(self, weight: float, P):
        """The prior's quadratic cost ½ λ xᵀPx on :attr:`prog`, described as :data:`SMOOTHNESS_PRIOR`."""
        binding = self.prog.AddQuadraticCost(weight * P, np.zeros(len(self.names)), self.variables, is_convex=True)
        binding.evaluator().set_description(SMOOTHNESS_PRIOR)
        return binding

    def add_smoothing_prior(self, weight: float) -> dict:
        """The smoothness prior at a stated weight on :attr:`prog`, not chosen and without a fit (a result's prior,
        re-added for its propagation: ``olti uncertainty``); later fits of the program use it as given."""
        from olti_drake.estimation.smoothing import SmoothingChoice

        self.options = dataclasses.replace(self.options, smoothing=float(weight))
        R = self.smoothing_rows()
        if R is None:
            raise InputError(f"{self.source}: a smoothness prior needs a model with error maps")
        P = np.asarray((R.T @ R).todense())
        binding = self._smoothing_binding(float(weight), P)
        choice = SmoothingChoice(float(weight), float("nan"), float("nan"), float("nan"), 0, method="given")
        self._smoothing = {"weight": float(weight), "P": P, "choice": choice, "rounds": 0, "x": self.x0.copy(),
                           "binding": binding}
        return self._smoothing

    def _smoothed_fit(self) -> "Fit":
        """:meth:`_fit` with the smoothness prior at its weight (:meth:`smoothing_weight`), with uncertainty: the
        residual variance over m − tr A (the readings less the parameters they determine), from the last solution
        of the weight's choice; the start is restored after."""
        state = self.smoothing_weight()
        lam, P, choice = state["weight"], state["P"], state["choice"]
        x0 = self.x0.copy()
        try:
            effective = choice.effective_parameters
            self.x0, self._effective = state["x"], effective if np.isfinite(effective) else None
            fit = self._fit()
        finally:
            self.x0, self._effective = x0, None
        auto = self.options.smoothing == "auto"
        fit.smoothing = {"method": choice.method if auto else "given", "weight": lam,
                         "score": choice.score if np.isfinite(choice.score) else None,
                         "effective_parameters": choice.effective_parameters, "readings": choice.readings,
                         "rounds": state["rounds"]}
        if state.get("group_weights"):
            fit.smoothing["group_weights"] = dict(state["group_weights"])
            if state.get("misfit") is not None and fit.covariance is not None and fit.sigma2 > 0:
                self._add_misfit(fit, state["misfit"])
        fit.notes.append(self._smoothing_note(fit, P, lam, choice, state.get("group_weights")))
        return fit

    def smoothing_misfit(self):
        """D (n, n) of :meth:`_group_misfit` -- what the maps' own roughness adds to the estimate's normal matrix in
        its covariance -- or None (one weight serves every map, or no prior yet)."""
        return (getattr(self, "_smoothing", None) or {}).get("misfit")

    @staticmethod
    def _add_misfit(fit: "Fit", D) -> None:
        """The maps' own roughness in the fit's covariance (:meth:`_group_misfit`): C + C D C / σ² (C = σ² H⁻¹ within
        the gauge): the estimate is the common weight's, its error that of maps rougher than that weight says."""
        C = np.asarray(fit.covariance)
        n = D.shape[0]
        extra = C[:, :n] @ D @ C[:n, :] / fit.sigma2
        fit.covariance = C + (extra + extra.T) / 2
        fit.std = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))

    def _linearized(self, z, lam: float, P) -> dict:
        """The smoothing scans' linearization at the solution z (all decision variables): ``H`` = JᵀWJ, ``Q`` the
        program's quadratic costs, ``Pn`` the prior's P over all variables, ``other`` the quadratic costs but the
        prior λP (None when there are none), ``g_data`` and ``g`` (the data's gradient; with the other costs'),
        ``A`` the linear equalities, ``rss`` = Σ w r², ``m`` readings, ``other0`` twice the other costs at z."""
        n = len(self.names)
        r, J = self.residuals(z[:n])
        w = self._weights(r)
        J = self._pad(J)
        H = _normal_matrix(J, w)
        g_data = J.T @ (w * r)
        Q, q = self.quadratic_costs()
        Pn = np.zeros_like(Q)
        Pn[:n, :n] = P
        Q_other = Q - lam * Pn
        return {"H": H, "Q": Q, "Pn": Pn, "other": Q_other if np.any(Q_other) else None, "g_data": g_data,
                "g": g_data + Q_other @ z + q, "A": self._equality_rows()[0], "rss": float(np.sum(w * r * r)),
                "m": len(r), "other0": float(z @ Q_other @ z + 2.0 * q @ z)}

    def _scan_smoothing(self, z, P, lam: float, given: bool = False):
        """The choice of the smoothness weight at the solution z (over all decision variables; its data, the
        program's other quadratic costs and equalities) by restricted maximum likelihood
        (:func:`~olti_drake.estimation.smoothing.reml_scan`); ``given``: only the statement of the weight ``lam``
        (its effective parameters)."""
        from olti_drake.estimation import smoothing as sm

        lin = self._linearized(z, lam, P)
        if given:
            tr = sm.effective_parameters(lin["H"], lin["H"] + lin["Q"], lin["A"])
            return sm.SmoothingChoice(lam, float("nan"), tr, lin["rss"], lin["m"], method="given")
        return sm.reml_scan(lin["H"], lin["other"], lin["Pn"], lin["g"], z, lin["A"], lin["rss"], lin["m"],
                            g_data=lin["g_data"], other0=lin["other0"], floor=self._smoothing_floor())

    def _smoothing_floor(self) -> float:
        """The reading variance (mm²) below which the smoothed fit's σ² is not taken: :meth:`reading_sigma`'s
        (the budget's; a stated one where the readings barely exceed the unknowns), so that maps able to run
        through every reading do not (:func:`~olti_drake.estimation.smoothing.reml_scan`)."""
        return float(self.reading_sigma()[0]) ** 2

    def _smoothing_note(self, fit: "Fit", P, lam: float, choice, group_weights=None) -> str:
        """What the prior did: its weight and how it was chosen, and the map values the readings leave to it."""
        n = len(self.names)
        _, J = self.residuals(fit.x)
        data = np.asarray(J.multiply(J).sum(axis=0)).ravel()[:n]
        prior = lam * np.diag(P)
        tied = set(getattr(self, "tied", ()))  # (tied nodes follow read ones: no prior's work)
        unread = [self.names[i] for i in np.flatnonzero((data == 0) & (prior > 0)) if self.names[i] not in tied]
        led = [self.names[i] for i in np.flatnonzero((data > 0) & (data < prior)) if self.names[i] not in tied]
        auto = fit.smoothing["method"] != "given"
        how = f"chosen by {choice.method}" if auto else "as given"
        score = f"-2 log likelihood {choice.score:.6g}, " if auto else ""
        text = (f"smoothness prior on {self.smoothing_subject}, weight "
                f"{lam:.4g} {how} ({score}{choice.effective_parameters:.1f} effective parameters of {n}, "
                f"{choice.readings} readings)")
        if choice.at_edge and auto:
            text += "; the choice lies at the end of the scanned weights"
        lighter = {g: w for g, w in (group_weights or {}).items() if w < lam * (1 - 1e-9)}
        if lighter:
            from olti_drake.estimation.smoothing import GROUP_RULE

            text += ("; in the u, each map's own roughness (" + GROUP_RULE + "), rougher than the common weight "
                     "says: " + ", ".join(f"{g} {w:.3g}" for g, w in sorted(lighter.items(), key=lambda kv: kv[1])))
        if unread:
            text += (f"; no reading reaches {_listing(unread)}: their values follow the prior (the neighbours' "
                     f"trend), not the readings")
        if led:
            text += f"; the prior outweighs the readings at {_listing(led)}"
        wide = self._wide_uncertainties(fit)
        if wide:
            text += (f"; u far beyond their peers' (over {self.WIDE_U_RATIO:g} x the median u of their map branch): "
                     f"{_listing(wide)}")
        return text

    #: A map value whose u exceeds this multiple of the median u of its branch is named (issue 23).
    WIDE_U_RATIO = 10.0
    #: What the smoothness prior acts on, as the fit's note says it (a model with other maps says its own).
    smoothing_subject = "the maps (second differences of each direction and of the backlash)"

    def _wide_uncertainties(self, fit: "Fit") -> list:
        """Indexed parameters (``name[i]``: the nodes of one map branch) whose u exceeds :data:`WIDE_U_RATIO`
        times their branch's median u."""
        if fit.std is None or not np.all(np.isfinite(fit.std)):
            return []
        branches = {}
        for i, name in enumerate(self.names):
            if "[" in name:
                branches.setdefault(name.split("[")[0], []).append(i)
        out = []
        for idx in branches.values():
            u = fit.std[idx]
            median = float(np.median(u))
            out += [self.names[i] for i, v in zip(idx, u) if median > 0 and v > self.WIDE_U_RATIO * median]
        return out

    def gross_outliers(self, fit: "Fit") -> list:
        """The readings of an l2 fit beyond :data:`GROSS_OUTLIER_SIGMA` robust sigma -- and as many budget reading
        u, when there is a budget (a noise-free simulation's rounding is no blunder): each the reading's label
        with ``residual_mm`` and ``normalized``, largest first. Empty for the Huber loss (it down-weights them)."""
        r = np.asarray(fit.residuals, dtype=float)
        if self.options.loss != "l2" or not r.size:
            return []
        zr = r / _robust_sigma(r)
        idx = np.flatnonzero(np.abs(zr) > GROSS_OUTLIER_SIGMA)
        if idx.size:
            budget = self.options.budget if self.options.budget is not None else self.default_budget()
            if budget is not None:
                from olti_drake.model.budget import ReadingErrors

                u = np.asarray(ReadingErrors(budget).std(self.beam_lengths(fit.x, fit.residuals)), dtype=float)
                u = u if u.shape == r.shape else np.full(r.shape, _rms(u))
                idx = idx[np.abs(r[idx]) > GROSS_OUTLIER_SIGMA * u[idx]]
        idx = idx[np.argsort(-np.abs(zr[idx]))]
        return [dict(self.reading_label(k), residual_mm=float(r[k]), normalized=float(zr[k])) for k in idx]

    def gross_outlier_warnings(self, fit: "Fit") -> list:
        """The warning that names the gross outliers (:meth:`gross_outliers`) of an l2 fit and the Huber loss."""
        self._gross = gross = self.gross_outliers(fit)
        if not gross:
            return []

        def where(o):
            label = f"line {o['line']}" if "line" in o else f"reading {o.get('row', '?')}"
            return f"{label} ({o['normalized']:+.1f} sigma, residual {o['residual_mm']:+.4g} mm)"

        shown = ", ".join(where(o) for o in gross[:5]) + (f" and {len(gross) - 5} more" if len(gross) > 5 else "")
        what = "a gross outlier" if len(gross) == 1 else f"{len(gross)} gross outliers"
        return [f"{what} beyond {GROSS_OUTLIER_SIGMA:g} robust sigma: {shown} -- a blunder (a misread or mistyped "
                f"reading), not a model error; the l2 fit spreads it over every parameter and every other warning "
                f"below: refit with --loss huber (loss='huber'), which down-weights it, or correct or remove the "
                f"reading"]

    def reduced_fit(self, T, y, x, rows, names, at=None, max_iterations: int = 20):
        """The same least squares on the readings ``rows`` only, over parameters T y: a linear
        reparametrization T (n, k) sparse, e.g. a map on every second node whose values at the dropped nodes
        are interpolated. Starts at ``y``; ``names`` name its columns. Returns (y, r) at the solution, r (mm)
        over *every* reading: the held-out ones predicted by the reduced fit.

        Solved on the model linearized at ``x``, the full fit's solution (``at``: its residuals and Jacobian,
        default evaluated): r(T y) ≈ r(x) + J (T y − x), no evaluation. The reduced fit lies a few
        uncertainties from x, where the model is linear far below the noise: the neglected term is second
        order in the step -- for a joint angle ½ Δθ² times the lever, 0.2 um for 0.05 deg over 550 mm, a
        thousandth of the miss such a step makes. Gauss-Newton with the first normal matrix kept: one step for
        the l2 loss; the Huber loss re-weights until no parameter would move by :data:`STEP_FRACTION` of its
        standard uncertainty (:meth:`_negligible_decrease`'s bound). The program's linear equalities on the
        model's parameters (gauge, fixed values) constrain the steps, mapped through T; the user's own
        variables, costs and priors are not part of it.

        Raises :class:`UnidentifiableError` naming what the rows cannot determine, InputError when the
        re-weighting does not settle."""
        n = len(self.names)
        rows = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        A = self._equality_rows()[0]
        A = np.asarray((T.T @ A[~np.any(A[:, n:] != 0, axis=1), :n].T).T)  # (rows on user variables left out)
        r, J = self.residuals(x) if at is None else at
        J = J[:, :n].tocsr()
        y = np.array(y, dtype=float)
        r = r + J @ (T @ y - x)  # the linear model at the start
        JT = (J @ T).tocsr()
        Jk, within = JT[rows], None
        for _ in range(max_iterations):
            rk = r[rows]
            w = self._weights(rk)
            g = Jk.T @ (w * rk)
            if within is None:
                within = self._reduced_factor(Jk, w, A, names)
            delta = within.to_full(within.solve(within.to_null(-g / within.s))) / within.s
            cost = 0.5 * float(np.sum(w * rk * rk))
            negligible = max(1e-12 * cost, _step_fraction_decrease(cost, len(rows) - within.dim))
            if -0.5 * float(g @ delta) <= negligible:  # (the Gauss-Newton step's predicted decrease)
                return y, r
            y, r = y + delta, r + JT @ delta
        raise InputError(f"{self.source}: the robust fit on the kept readings did not settle in {max_iterations} "
                         f"re-weightings")

    def _reduced_factor(self, J, w, A, names) -> "Within":
        """:class:`Within` of :meth:`reduced_fit`'s normal matrix, or UnidentifiableError naming what it lacks (not
        :meth:`_explain`ed: the campaign's readings are not at fault for what a subset of them cannot see)."""
        H = _normal_matrix(J, w)
        untouched = [names[i] for i in np.flatnonzero(np.diag(H) == 0)]
        if untouched:
            raise UnidentifiableError(f"not identifiable from the kept readings: {_listing(untouched)} -- no kept "
                                      f"reading touches {'it' if len(untouched) == 1 else 'them'}", untouched)
        within = Within(H, A, large=True, overwrite=True)
        weak = [] if within.clearly_regular() else within.weak_names(names)
        if weak:
            raise UnidentifiableError(f"not identifiable from the kept readings: {_listing(weak)} -- a combination "
                                      f"of them leaves every kept reading unchanged", weak)
        return within

    # -- acceptance: refuse what is not to be trusted, state what is doubtful ---------------------
    def accept(self, fit: "Fit") -> None:
        """Raise :class:`FitRefused` (one line) unless the fit converged, its covariance is finite and
        positive definite within the gauge, and :meth:`implausible` finds nothing."""
        where = f"{self.source}: refused, nothing written --"
        if not fit.converged_by:
            moving = getattr(self, "_moving", None)
            kept = f"; still moving: {moving}" if moving else ""
            more = " or allow more iterations (--max-iterations)" if getattr(self, "_stop", None) is None else ""
            raise FitRefused(f"{where} the solver did not converge: {self._stop_text()} after {fit.iterations} "
                             f"iterations (residual RMS {1e3 * _rms(fit.residuals):.4g} um){kept}; check the units "
                             f"(mm), the nominal values and the start{more}")
        std_ok = np.isfinite(fit.std) | (not self._uncertainty)  # (NaN: none asked for)
        bad = [self.names[i] for i in np.flatnonzero(~np.isfinite(fit.x) | ~std_ok)]
        if bad:
            raise FitRefused(f"{where} non-finite estimate or uncertainty of {_listing(bad)}")
        if self._weak:
            raise FitRefused(f"{where} the covariance is singular within the gauge (condition number "
                             f"{fit.condition_number:.3g}): {_listing(self._weak)} not determined by the readings "
                             f"at the solution")
        problems = self.implausible(fit.x)
        if problems:
            cause = self.implausible_cause(fit)
            raise FitRefused(f"{where} {cause + ' -- it gives a ' if cause else ''}physically impossible solution: "
                             f"{'; '.join(problems)}")
        if self._uncertainty and fit.std is not None and np.all(np.isfinite(fit.std)):
            vague = self._vague_error(fit.std, "u at the solution", VagueSolution)
            if vague is not None:
                vague.args = (f"{where} {vague}",)
                raise vague

    def implausible_cause(self, fit: "Fit") -> str:
        """Hook: the input at fault for a physically impossible solution (e.g. given values in another unit),
        named first in the refusal; "" when none is known."""
        return ""

    def _user_costs(self):
        """The program's costs other than the data cost (which the solvers evaluate themselves)."""
        data = self.data_cost.evaluator()
        return [b for b in self.prog.GetAllCosts() if b.evaluator() is not data]

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
        if stop is not None:
            return stop[1]
        cap = getattr(self, "_cap_used", None) or self.iteration_cap()
        option = "" if isinstance(self.options.max_iterations, SizeCap) else " (max_iterations)"
        return f"iteration cap {cap}{option} reached"

    def residual_warnings(self, fit: "Fit") -> list:
        """A warning when the residual RMS exceeds :data:`RESIDUAL_WARNING_RATIO` times the reading
        uncertainty the budget predicts (RMS over the readings, at each reading's beam length), mm."""

        budget = self.options.budget if self.options.budget is not None else self.default_budget()
        if budget is None or not len(fit.residuals):
            return []
        u = _rms(ReadingErrors(budget).std(self.beam_lengths(fit.x, fit.residuals)))
        rms = _rms(fit.residuals)
        ratio = rms / max(u, 1e-300)
        self.residual_ratio = (float(ratio), float(u), getattr(budget, "name", ""))
        # Far BELOW the budget's (real) u: exact readings of a simulation, or readings in another unit. Refused
        # only with the unit slip's signature too -- readings spread far less than the robot or machine moves
        # (the measurement's reading_spans(): readings in metres spread 1/1000 of the motion) -- never for a
        # noise-free simulated campaign, whose readings spread like the motion.
        spans = getattr(getattr(self, "measurement", None), "reading_spans", None)
        if ratio < 1e-2 and u >= 1e-6 and spans is not None:
            spread, motion = spans()
            if spread < 1e-2 * motion:
                raise FitRefused(f"{self.source}: refused, nothing written -- residual RMS {1e3 * rms:.3g} um is "
                                 f"below 1/100 of the reading uncertainty {1e3 * u:.3g} um and the readings spread "
                                 f"{spread:.4g} mm while the tool points spread {motion:.4g} mm: readings in "
                                 f"another unit (metres?), not mm")
        if ratio <= RESIDUAL_WARNING_RATIO:
            return []
        return [f"residual RMS {1e3 * rms:.2f} um is {ratio:.1f} x the reading uncertainty {1e3 * u:.2f} um that "
                f"the budget '{budget.name}' predicts (warning above {RESIDUAL_WARNING_RATIO:g} x): a model error "
                f"(e.g. a map too coarse), a budget that does not fit the instrument, or readings in other units"
                + (" -- or the gross outlier(s) above" if getattr(self, "_gross", None) else "")]

    def _fit(self) -> "Fit":
        o = self.options
        self._solver_used = "lm: Levenberg-Marquardt, steps solved by Drake"
        given = getattr(self, "_given", None)
        defer = given is None and o.solver == "lm" and self.n_all > REUSE_ABOVE
        try:
            for _ in range(len(self.names)):
                try:
                    self.check_identifiability(defer=defer)
                    later = getattr(self, "_deferred", False)  # (the large path's variances: beside the solver)
                    if not later:
                        self._raise_if_vague()
                    x, iterations, weights = (self._solve_given(*given) if given is not None else
                                              self._solve_lm() if o.solver == "lm" else self._solve_nlp())
                    self._confirm_identifiable()
                    if later:
                        self._raise_if_vague()
                    break
                except UnidentifiableError as e:
                    if not o.regularize:
                        raise self._real_cause(e)
                    self._regularize(e)
            return self._finish(x, iterations, weights)
        except np.linalg.LinAlgError as e:  # numpy's bare "Singular matrix" / "SVD did not converge": say why
            raise self._real_cause(e) from None
        finally:
            within, self._within0 = getattr(self, "_within0", None), None  # (n x n): done with it
            if within is not None:
                within.wait()

    def _reading_spans(self):
        """(the readings' spread, the spread of the points they are read at), mm, or None: the measurement's
        ``reading_spans()`` (every measurement of the package has one)."""
        spans = getattr(getattr(self, "measurement", None), "reading_spans", None)
        return spans() if spans is not None else None

    def _real_cause(self, error: Exception) -> Exception:
        """The error to raise for ``error`` (unidentifiable, or a numpy LinAlgError) of the solve: readings in
        another unit when they spread under 1/100 of the points they are read at (a rank or a singular matrix
        then says nothing of the layout); a LinAlgError as what the readings cannot determine; else ``error``."""
        try:
            spans = self._reading_spans()
        except Exception:  # a diagnosis only: never hide the error it explains
            spans = None
        source = getattr(self, "source", "") or getattr(getattr(self, "data", None), "source", "") or "the campaign"
        if spans is not None and spans[0] < 1e-2 * spans[1]:
            return InputError(f"{source}: refused, nothing written -- the readings spread {spans[0]:.4g} mm while "
                              f"the points they are read at spread {spans[1]:.4g} mm: readings in another unit "
                              f"(metres?), not mm")
        if isinstance(error, np.linalg.LinAlgError):
            text = " ".join(str(error).split()) or type(error).__name__
            return InputError(f"{source}: refused, nothing written -- the readings cannot determine the "
                              f"parameters (the solver's linear algebra failed: {text}): check the readings' unit "
                              f"(mm) and sign (formats.md), and that no two stations or reflectors coincide")
        return error

    def given_solution(self, z, solver: str):
        """Context: :meth:`fit` (and a model's ``solve`` built on it) takes ``z`` (over all decision variables,
        model units) as the solution another solver found (``solver`` names it), instead of solving -- the same
        identifiability check, covariance, outliers and acceptance (a solution off the minimum is refused by
        what it is: e.g. a parameter a reading cannot determine, or an implausible value)."""
        import contextlib

        @contextlib.contextmanager
        def given():
            self._given = (np.asarray(z, dtype=float).copy(), solver)
            try:
                yield self
            finally:
                self._given = None
        return given()

    def _solve_given(self, z, solver: str):
        """:meth:`_fit`'s step for a solution found elsewhere (:meth:`given_solution`): its residuals, Jacobian
        and the loss's weights there."""
        if z.shape != (self.n_all,) or not np.all(np.isfinite(z)):
            raise InputError(f"{self.source}: the solution of {solver} has {z.size} values for the program's "
                             f"{self.n_all} decision variables, or non-finite ones")
        r, J = self.residuals(z[:len(self.names)])
        self._final = (z, r, J)
        self._solver_used = solver
        self._stop = (True, f"{solver} reports success")
        return z, 0, self._weights(r)

    def _weights(self, r):
        """IRLS weights w = ψ(r)/r of the loss at residuals r, with a = |r| / c, c = k x the robust sigma (k =
        ``huber_k``): Huber min(1, 1/a); soft-L1 (pseudo-Huber, ρ = 2c²(√(1 + a²) − 1)) 1/√(1 + a²); Cauchy
        (ρ = c² log(1 + a²)) 1/(1 + a²); l2 1."""
        loss = self.options.loss
        if loss == "l2":
            return np.ones_like(r)
        sigma = _robust_sigma(r)
        a = np.abs(r) / (self.options.huber_k * sigma)
        if loss == "soft_l1":
            return 1.0 / np.sqrt(1.0 + a * a)
        if loss == "cauchy":
            return 1.0 / (1.0 + a * a)
        if loss != "huber":
            raise InputError(f"loss {loss!r} has no weights (l2, huber, soft_l1, cauchy)")
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
        # Large problems with linear equalities and quadratic costs only: steps by conjugate gradients within
        # the constraints, preconditioned by the factorization of the identifiability check (no n x n work).
        prior = None
        if self._steps_by_cg():
            prior = self.quadratic_costs() if self._has_quadratic_costs() else (None, None)
        self._moving = None
        recent = []  # the last MOVING_STEPS accepted steps (a refusal names what kept moving)
        decreases = []  # the cost's decrease at the last accepted steps (:meth:`_crawl_done`)
        self._cap_used = self.iteration_cap()
        for _ in range(self._cap_used):
            self._confirm_identifiable(wait=False)
            w = self._weights(r)
            H = _NormalOperator(J, w) if prior is not None else self._normal(J, w)
            g = J.T @ (w * r)
            user = self._user_cost(x)
            cost = 0.5 * np.sum(w * r * r) + user
            # Quadratic user costs carry no constant term, so the cost may be negative: tolerances on |cost|.
            # Exact readings (a synthetic campaign) leave a cost at the rounding floor of the residuals
            # themselves, eps times the coordinates' size: below it no step can show a decrease.
            floor = 4.0 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(x)))) * float(np.sum(w * np.abs(r)))
            tol = max(1e-12 * abs(cost), floor)
            negligible = max(1e-12 * abs(cost), self._negligible_decrease(r, w))
            while True:
                # The user's own variables carry no curvature of the data: damp them by the mean one.
                D = H.diagonal().copy()
                D[D == 0] = np.mean(D[D > 0]) if (D > 0).any() else 1.0
                delta = (self._cg_step(x, H, lam * D, g, prior) if prior is not None
                         else self._step(x, H + lam * np.diag(D), g))
                # What the quadratic model promises: below 1e-12 of the cost, or a step no parameter would notice
                # (:meth:`_negligible_decrease`), we are at the minimum, known before evaluating the step (at
                # large scale an evaluation is a sixth of the fit's time). Not at the rounding floor of exact
                # readings: there the step is still taken, and judged by its cost.
                # (The user's costs are linear or quadratic: their change is exact.)
                x_new = x + delta
                user_new = self._user_cost(x_new)
                predicted = -(g @ delta + 0.5 * delta @ (H @ delta)) + user - user_new
                if predicted <= negligible:
                    break
                r_new, J_new = self.residuals(x_new[:n])
                J_new = self._pad(J_new)
                cost_new = 0.5 * np.sum(w * r_new * r_new) + user_new
                if cost_new <= cost or predicted <= tol or lam > 1e12:
                    break
                lam *= 8.0
            if predicted <= negligible or cost_new > cost:
                # No step lowers the cost: at the minimum if the quadratic model promised nothing more.
                at_minimum = predicted <= max(tol, negligible) + 1e-300
                self._stop = (True, (f"the next step would change no parameter by more than {STEP_FRACTION:.0%} "
                                     f"of its standard uncertainty" if negligible > 1e-12 * abs(cost) else
                                     "the predicted cost decrease is below 1e-12 of the cost (or the rounding "
                                     "floor of exact readings)")) if at_minimum else (
                    False, f"no step lowers the cost (damping {lam:.0e}) though the model predicts "
                           f"{predicted / max(abs(cost), 1e-300):.1e} of it")
                break
            if recent and self._extrapolable() and _parallel(delta, recent[-1], D):
                delta, x_new, r_new, J_new, cost_new = self._extrapolate(x, delta, w, (x_new, r_new, J_new, cost_new))
            x, r, J, steps = x_new, r_new, J_new, steps + 1
            recent = (recent + [delta])[-MOVING_STEPS:]
            decreases = (decreases + [cost - cost_new])[-(CRAWL_RATE_STEPS + 1):]
            lam = max(lam / 4.0, 1e-9)
            if cost - cost_new <= tol:
                self._stop = (True, "the relative cost decrease of the last step is below 1e-12")
                break
            crawl = self._crawl_done(steps, decreases, r, w)
            if crawl:
                self._stop = (True, crawl)
                break
            problems = (self.implausible(x[:n]) if steps >= OUT_OF_BOUNDS_AFTER and steps % OUT_OF_BOUNDS_AFTER == 0
                        else [])
            if problems:
                # Still beyond physical bounds after so many steps: no iteration leads back (readings in metres,
                # a wrong model file) -- stop here, not converged, naming what is impossible.
                self._stop = (False, f"stopped at a physically impossible solution ({'; '.join(problems)})")
                break
        self._final = (x, r, J)
        if self._stop is None and recent:
            self._moving = self._moving_text(np.sum(recent, axis=0), len(recent), r, self._weights(r))
        return x, steps, self._weights(r)

    def _crawl_done(self, steps: int, decreases, r, w) -> str:
        """The stop of a linear convergence, or "": after :data:`CRAWL_AFTER` steps, when the cost's decrease
        falls geometrically (ratio ρ < 1 over the last :data:`CRAWL_RATE_STEPS` steps), what is left of it,
        d ρ / (1 − ρ), is below the decrease by which a step could move a parameter by :data:`STEP_FRACTION` of
        its u (½ f² σ̂², :meth:`_negligible_decrease`'s bound applied to the rest at once). Gauss-Newton converges
        linearly where the readings barely fix a direction and the residuals' own curvature (Σ r ∇²r, which it
        leaves out) is comparable there: a five-axis error map from 100 readings crawled to its cap of 2000 steps
        with each step's decrease exactly as predicted, 2 % smaller each time. σ̂² the residual variance over the
        redundant readings, or the readings' u (:meth:`reading_sigma`) where they are fewer than the unknowns
        (a map determined by its smoothness prior)."""
        if steps < CRAWL_AFTER or len(decreases) <= CRAWL_RATE_STEPS or min(decreases) <= 0.0:
            return ""
        rho = (decreases[-1] / decreases[0]) ** (1.0 / CRAWL_RATE_STEPS)
        if not rho < 1.0:
            return ""
        dof = len(r) - self.n_all
        sigma2 = (float(np.sum(w * r * r)) / dof if dof >= max(10, 0.1 * len(r)) else
                  float(self.reading_sigma()[0]) ** 2)
        rest = decreases[-1] * rho / (1.0 - rho)
        if rest > 0.5 * STEP_FRACTION ** 2 * sigma2:
            return ""
        return (f"the cost's decrease falls by {1 - rho:.1%} a step (linear convergence): what is left of it, "
                f"{rest:.2e} mm², would change no parameter by more than {STEP_FRACTION:.0%} of its standard "
                f"uncertainty")

    def _extrapolable(self) -> bool:
        """Whether a step may be lengthened (:meth:`_extrapolate`): the program's constraints are equalities
        only (a step within them stays within them at any length)."""
        cached = getattr(self, "_equalities_only", None)
        if cached is None:
            cached = self._equalities_only = all(
                np.all(b.evaluator().lower_bound() == b.evaluator().upper_bound())
                for b in self.prog.GetAllConstraints())
        return cached

    def _extrapolate(self, x, delta, w, accepted):
        """The accepted step ``delta`` (its point, residuals, Jacobian and cost ``accepted``) lengthened 2, 4, 8 ...
        times while the cost keeps falling (at most :data:`EXTRAPOLATIONS` times). Gauss-Newton leaves out the
        residuals' own curvature (Σ r ∇²r): where the readings barely fix a direction and the residuals hold a
        lack of fit, its steps along that direction come out short by the same factor each time and LM crawls
        there (R-test paths on a 30° map grid: 2e-6 of the cost per step, over a thousand steps). Taken only
        after two steps in the same direction (:func:`_parallel`), so a fit that converges as Gauss-Newton does
        is not changed."""
        n = len(self.names)
        best = accepted
        alpha = 1.0
        for _ in range(EXTRAPOLATIONS):
            alpha *= 2.0
            xa = x + alpha * delta
            ra, Ja = self.residuals(xa[:n])
            ca = 0.5 * np.sum(w * ra * ra) + self._user_cost(xa)
            if not np.isfinite(ca) or ca >= best[3]:
                break
            best = (xa, ra, self._pad(Ja), ca)
        return (best[0] - x,) + best

    def iteration_cap(self) -> int:
        """LM's iteration cap: ``max_iterations`` as given, or (the default :data:`SIZE_CAP`) fitting the problem's
        size, max(100, :data:`ITERATIONS_PER_UNKNOWN` x the unknowns within the constraints, at most
        :data:`MAX_SIZE_CAP`)."""
        cap = self.options.max_iterations
        if isinstance(cap, SizeCap):
            within = getattr(self, "_within0", None)
            return cap.cap(within.dim if within is not None else self.n_all)
        return int(cap)

    def _moving_text(self, change, steps: int, r, w) -> str:
        """The parameters that kept moving: the largest changes over the last ``steps`` LM steps relative to
        their standard uncertainty at the start (the identifiability check's factorization times the residual
        variance; their column scale 1/√(JᵀJ)_ii when it is not at hand), one phrase."""
        names = self._all_names()
        n = len(change)
        scale, what = None, "u"
        within = getattr(self, "_within0", None)
        try:
            if within is not None:
                sigma2 = float(np.sum(w * r * r)) / max(len(r) - within.dim, 1)
                scale = np.sqrt(np.maximum(within.inverse_diagonal()[:n] * sigma2, 0.0))
        except Exception:  # (a diagnosis only: never hide the refusal it explains)
            scale = None
        if scale is None or not np.all(np.isfinite(scale)) or not np.any(scale > 0):
            scale, what = 1.0 / within.s[:n] if within is not None else np.ones(n), "its scale"
        rel = np.abs(change) / np.where(scale > 0, scale, np.inf)
        top = [i for i in np.argsort(-rel)[:MOVING_NAMED] if rel[i] > 0]

        def unit(name):
            return " mm" if "_mm" in name else " deg" if "_deg" in name else ""
        return ", ".join(f"{names[i]} {change[i]:+.4g}{unit(names[i])} ({rel[i]:.3g} {what})" for i in top) + (
            f" over the last {steps} step(s)")

    def _negligible_decrease(self, r, w) -> float:
        """The predicted cost decrease of a step that changes no parameter by more than :data:`STEP_FRACTION`
        of its standard uncertainty: ½ f² σ̂², σ̂² = Σ w r² / (m − n) the residual variance. A Gauss-Newton
        step δ predicts ½ δᵀHδ (more when damped), and |δ_i| ≤ √(δᵀHδ · C_ii) = √(δᵀHδ) σ_i / σ̂ with
        C = H⁻¹ within the constraints (Cauchy-Schwarz in H's metric): below this, each |δ_i| ≤ f σ_i.
        0 without redundant readings (σ̂ unknown; for exact readings it lies at the rounding floor anyway),
        and off the large path (:meth:`_large`: up to :data:`LARGE_PROBLEM` variables with uncertainty): there
        an evaluation costs milliseconds, and LM goes on to 1e-12 of the cost (results the same to rounding
        whichever solver or path)."""
        return _step_fraction_decrease(0.5 * float(np.sum(w * r * r)), len(r) - self.n_all) if self._large() else 0.0

    def _steps_by_cg(self) -> bool:
        """Large path (:data:`LARGE_PROBLEM`) for LM steps: only linear equalities and quadratic costs on the
        program, and the identifiability check's factorization at hand."""
        from pydrake.solvers import BoundingBoxConstraint, LinearConstraint, QuadraticCost

        if not self._large() or getattr(self, "_within0", None) is None:
            return False
        for b in self.prog.GetAllConstraints():
            e = b.evaluator()
            if not isinstance(e, (LinearConstraint, BoundingBoxConstraint)) or np.any(e.lower_bound() !=
                                                                                     e.upper_bound()):
                return False
        return all(isinstance(b.evaluator(), QuadraticCost) for b in self._user_costs())

    def _cg_step(self, x, H, damping, g, prior):
        """The LM step of :meth:`_step` for the large path: min ½δᵀ(H + diag(damping) + Q)δ + (g + Qx + q)ᵀδ
        with A δ = 0 (x is feasible), by preconditioned conjugate gradients on the null space of the scaled
        constraints (preconditioner: the Cholesky factor of the identifiability check's reduced normal
        matrix); if they do not converge (a large damping, a far iterate), one factorization of the damped
        matrix itself."""
        Q, q = prior  # (None, None) without quadratic costs
        has_prior = Q is not None
        W = self._within0
        s = W.s
        grad = g + (Q @ x + q if has_prior else 0.0)

        def apply(z):
            v = W.to_full(z) / s
            Hv = H @ v + damping * v + (Q @ v if has_prior else 0.0)
            return W.to_null(Hv / s)

        z, ok = _pcg(apply, -W.to_null(grad / s), W.solve)
        if ok:
            return W.to_full(z) / s
        Hd = _normal_matrix(H.J, H.w) + np.diag(damping) + (Q if has_prior else 0.0)
        direct = self.within(Hd)
        return direct.to_full(direct.solve(-direct.to_null(grad / direct.s))) / direct.s

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
        """Solve the LM step program: min ½δᵀHdδ + gᵀδ + user costs, s.t. the program's constraints at x + δ.
        The step program is built once for the program's bindings (:class:`_StepProgram`) and updated per step."""
        from pydrake.solvers import Solve

        key = (self.n_all, len(self.prog.GetAllConstraints()), len(self.prog.GetAllCosts()))
        cached = getattr(self, "_step_program", None)
        step = None if cached is None or cached.key != key else cached.at(x, Hd, g)
        if step is None:
            cached = self._step_program = _StepProgram(self.prog, self.n_all, self.data_cost.evaluator(), key)
            step = cached.at(x, Hd, g)
        step, d = step
        result = Solve(step)
        if not result.is_success():
            # EqConstrainedQP can refuse a nearly singular KKT system at the optimum: retry interior-point.
            from pydrake.solvers import ClarabelSolver
            result = ClarabelSolver().Solve(step)
        if not result.is_success():
            raise InputError(f"the constraints added to the program cannot be satisfied "
                             f"({result.get_solver_id().name()}: {result.get_solution_result()})")
        return result.get_x_val()  # = GetSolution(d): δ is the step program's only variables, in order

    def _solve_nlp(self):
        """The program itself (data cost, user variables, constraints, costs) by the solver Drake picks;
        Huber loss: three IRLS rounds re-weighting the data cost."""
        from pydrake.solvers import Solve, SolutionResult

        z = self._start()
        all_vars = self.prog.decision_variables()
        rounds = 3 if self.options.loss in ROBUST_LOSSES else 1
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

    def _has_quadratic_costs(self) -> bool:
        from pydrake.solvers import QuadraticCost

        return any(isinstance(b.evaluator(), QuadraticCost) for b in self._user_costs())

    def _prior_hessian(self):
        """Q of :meth:`quadratic_costs`, or None when the program has no quadratic cost (no n x n zeros to form
        and scan at thousands of unknowns)."""
        return self.quadratic_costs()[0] if self._has_quadratic_costs() else None

    def _finish(self, z, iterations, weights) -> "Fit":
        n = len(self.names)
        final = getattr(self, "_final", None)
        r, J = final[1:] if final is not None and final[0] is z else self.residuals(z[:n])
        J = self._pad(J)
        if not self._uncertainty:
            return self._solution_only(z, r, iterations)
        # Priors (user costs, regularization) inform the estimate: include them in the covariance.
        prior = self._prior_hessian()
        # The model's own work at the solution beside the reuse test of large problems (a second core).
        within = data = in_parallel(lambda: self._start_factor(J, weights, prior), lambda: self.at_solution(z[:n], r, J),
                                    parallel=self.n_all > REUSE_ABOVE)[0]
        if within is None:
            H = self._normal(J, weights)
            within = self.within(H + prior) if prior is not None else None
            data = self.within(H, overwrite=True)
            within = within or data
        # (smoothed: the problem solved is the readings' and the prior's -- the readings alone need not determine
        # a fine map, the prior does)
        cond = (within if getattr(self, "_effective", None) is not None else data).condition()
        self._stop = getattr(self, "_stop", (True, "solved"))
        self._weak = within.weak_names(self._all_names())  # what the covariance (with priors) cannot determine
        # With a smoothness prior, the parameters the readings determine are tr A (< dim): the residual variance
        # divides by the readings less them (:meth:`_smoothed_fit`).
        effective = getattr(self, "_effective", None)
        dof = max(len(r) - (within.dim if effective is None else effective), 1)
        sigma2 = np.sum(weights * r * r) / dof
        lack = self.lack_of_fit(sigma2)
        if effective is not None:  # the smoothed fit's σ², as its weight's choice took it (not below the floor)
            sigma2 = max(sigma2, self._smoothing_floor())
        if within.large:  # the variances from the factor; the (n, n) matrix only when read
            var = within.inverse_diagonal()[:n] * sigma2
            cov_x = lambda: within.inverse()[:n, :n] * sigma2  # noqa: E731
        else:
            cov_x = (within.inverse() * sigma2)[:n, :n]
            var = np.diag(cov_x)
        zr = r / _robust_sigma(r)
        order = np.argsort(-np.abs(zr))
        out = [dict(self.reading_label(k), residual_mm=float(r[k]), normalized=float(zr[k]))
               for k in order[np.abs(zr[order]) > self.options.outlier_threshold]]
        fit = self._make_fit(z, np.sqrt(np.maximum(var, 0)), cov_x, r, iterations, cond, out)
        fit.sigma2 = float(sigma2)
        fit.lack_of_fit_mm = lack[0]
        if lack[1]:
            fit.notes.append(lack[1])
        return fit

    #: A lack of fit below this share of the residuals' σ is not stated (the residuals are the readings' noise).
    LACK_OF_FIT_SHARE = 0.25
    #: Whether this kind's predictions add :meth:`lack_of_fit` to their u (and its fits state it).
    predicts_lack_of_fit = False

    def lack_of_fit(self, sigma2: float):
        """(e mm, note): the model's own error at a prediction -- what the residuals' variance σ² (mm², over the
        readings less the parameters they determine) holds beyond the readings' u. The parameters' covariance
        σ² (JᵀJ)⁻¹ is the error of the fit's estimate; a point the model predicts also carries the model's
        misfit, which the residuals show and a truth outside the model family has everywhere (a geometric model
        of a robot with joint deviations; maps between their nodes): e² = σ² − u_reading², u_reading of
        :meth:`reading_sigma` (the budget's; without one the residuals' at the start, or a stated one where the
        readings barely exceed the unknowns). 0 where it is below :data:`LACK_OF_FIT_SHARE` of σ (the residuals
        are the readings' noise)."""
        if not self.predicts_lack_of_fit:
            return 0.0, ""
        sigma = float(np.sqrt(max(sigma2, 0.0)))
        reading, what = self.reading_sigma()
        e = float(np.sqrt(max(sigma2 - reading ** 2, 0.0)))
        if not np.isfinite(e) or e <= self.LACK_OF_FIT_SHARE * sigma or e == 0.0:
            return 0.0, ""
        return e, (f"lack of fit: the residuals' sigma {1e3 * sigma:.3g} um exceeds the readings' u of "
                   f"{1e3 * reading:.3g} um ({what}): a model error of {1e3 * e:.3g} um that every predicted point "
                   f"and reading shares is added to their u")

    def at_solution(self, x, r, J) -> None:
        """Hook: a model's own work at the solution x (residuals r, Jacobian J) that needs no covariance -- e.g.
        the SCARA's under-resolution check. :meth:`fit` runs it before the covariance (on large problems while
        the helper thread still computes the variances); the fit may still be refused after it."""

    def _solution_only(self, z, r, iterations) -> "Fit":
        """:meth:`fit` without uncertainty: x, residuals and the stop; std NaN, covariance None, no outliers
        flagged (their normalization needs no covariance, but nothing reads them here)."""
        self._weak = []
        self._stop = getattr(self, "_stop", (True, "solved"))
        within = getattr(self, "_within0", None)
        cond = within.condition() if within is not None else float("nan")
        return self._make_fit(z, np.full(len(self.names), np.nan), None, r, iterations, cond, [])

    def _make_fit(self, z, std, covariance, r, iterations, cond, outliers) -> "Fit":
        """The :class:`Fit` of the solution z: the solver's label, the notes, the stop reason, the user's values."""
        stop = self._stop
        return Fit(list(self.names), z[:len(self.names)], std, covariance, r, iterations, cond,
                   f"{self._solver_used} ({self.options.loss} loss)", outliers, list(self.notes),
                   stop[1] if stop is not None and stop[0] else "", extra=self._extra_values(z))

    def _start_factor(self, J, w, prior):
        """The identifiability check's factorization (at the start), when it may serve the covariance at the
        solution: above :data:`REUSE_ABOVE` variables, no priors, and the normal matrices at the start and the
        solution differing by at most :data:`REUSE_TOLERANCE` in its metric (:meth:`Within.metric_change`):
        every variance is then within that factor of the solution's. None otherwise (refactorize)."""
        within, checked = getattr(self, "_within0", None), getattr(self, "_checked", None)
        if (within is None or checked is None or self.n_all <= REUSE_ABOVE or not within.factorized
                or prior is not None):
            return None
        J0 = self._pad(checked[2])
        eps = within.metric_change(J0, np.ones(J0.shape[0]), J, w)
        if not eps <= REUSE_TOLERANCE:
            return None
        stated = _round_up(eps)
        self.notes.append(f"standard uncertainties and condition number from the identifiability check's "
                          f"factorization at the start: the normal matrices at the start and at the solution differ "
                          f"by {stated:.2g} in its metric (estimated), so every variance is within that factor of "
                          f"the solution's (u within {50 * stated:.2g} %)")
        return within


# -- the algebra within the constraints ------------------------------------------------------------
class Within:
    """A normal matrix H (n, n) within the program's linear equalities A x = b, factorized once.

    M = Nᵀ (H / s sᵀ) N with s = √diag H (1 where 0) and N an orthonormal basis of the null space of A / s
    (the scaled coordinates y = s x); rank, condition number, covariance (N/s) M⁻¹ (N/s)ᵀ and steps within
    the constraints all come from it.

    * dense (``large`` False, the small problems): N explicit (SVD of A / s), M's eigen-decomposition --
      the reference, exactly what the program always did;
    * large: N kept as the Householder reflectors of (A / s)ᵀ (pivoted QR: m constraints, O(n m) storage),
      M = (Qᵀ H_s Q)[r:, r:] by applying them to both sides (O(n² m), no n³ product), a Cholesky factor
      U of M (M = UᵀU), the extreme eigenvalues by Lanczos (ARPACK) on M and on M⁻¹ through U, the
      standard uncertainties from the rows of N U⁻¹ (one triangular inverse; the full covariance only when
      asked for). Eigen-decomposition only to name what is not identifiable, on the refusal's path.
    """

    def __init__(self, H, A, large: bool, overwrite: bool = False):
        """``overwrite``: H (dense) may be used as work space."""
        H = H.toarray() if sp.issparse(H) else np.asarray(H, dtype=float)
        d = np.diag(H)
        self.s = np.where(d > 0, np.sqrt(np.maximum(d, 0)), 1.0)
        self.large = large
        self.n = len(self.s)
        As = A / self.s if A.size else np.zeros((0, self.n))
        self._U = self._K = self._lam = self._vec = self._N = self._extremes = self._diag = self._M = None
        if not large:
            self._N = _null_space(As) if As.size else np.eye(self.n)
            self._M = self._N.T @ (H / np.outer(self.s, self.s)) @ self._N
            self._dim, self._finite = self._M.shape[0], bool(np.all(np.isfinite(self._M)))
            return
        self._householder(As)
        Hs = H if overwrite else H.copy()
        Hs /= self.s[:, None]
        Hs /= self.s[None, :]
        # Hs is symmetric: its transpose is the same numbers in Fortran order, which LAPACK overwrites in place.
        QHQ = self._apply_q(self._apply_q(Hs.T, "L", "T", overwrite=True), "R", "N", overwrite=True)
        # At thousands of unknowns every n x n array costs a pass and fresh pages: M = QHQ[r:, r:] is moved to
        # the front of the same memory and factorized in place -- U in its upper triangle, M's strict lower
        # triangle kept (its diagonal saved) for the products with M and the refusal's eigen-decomposition.
        M = _leading_block(QHQ, self.r)
        self._dim, self._finite = M.shape[0], bool(np.all(np.isfinite(M)))
        self._M_diag = np.diag(M).copy()
        with _factor_threads(self._dim):
            packed, info = lapack.dpotrf(M, lower=0, clean=0, overwrite_a=1)
        self._packed = packed
        self._diag_fix = self._M_diag - np.diag(packed)  # dsymv on the lower triangle sees U's diagonal
        self._U = packed if info == 0 and self._finite and np.all(np.isfinite(np.diag(packed))) else None

    @property
    def dim(self) -> int:
        """Dimension of the null space (the free parameter combinations)."""
        return self._dim

    @property
    def M(self) -> np.ndarray:
        """Nᵀ (H / s sᵀ) N (dim, dim); on the large path rebuilt on demand from the factor's memory (the
        refusal's eigen-decomposition, tests) -- the factor uses only its upper triangle."""
        if self._M is None:
            lower = np.tril(self._packed, -1)
            self._M = lower + lower.T + np.diag(self._M_diag)
        return self._M

    def _times_M(self, v) -> np.ndarray:
        """M v (large path) from the lower triangle kept beside the factor."""
        return symmetric_times(self._packed, v) + self._diag_fix * v  # (releases the GIL: see threads)

    @property
    def factorized(self) -> bool:
        """Large path with a Cholesky factor of M (M numerically positive definite)."""
        return self._U is not None

    # -- reporting work beside the solver --------------------------------------------------------
    def start_background(self) -> None:
        """Compute the extreme eigenvalues and the variances in a thread (large path, factorized): the long
        LAPACK calls release the GIL, so on a second core this runs beside the solver's evaluations. The
        accessors wait for it; the results are the same numbers as computed in line. The extremes come first
        and are announced on their own (:meth:`extremes_ready`): the rank decides while the variances are
        still being computed (the solver's work at the solution goes on beside them)."""
        import threading

        ready = self._ready = threading.Event()

        def work():
            try:
                self._extremes = self._compute_extremes()
                ready.set()
                self._diag = self._row_norms()
            except BaseException as e:  # re-raised by wait(), in the caller's thread
                self._job_error = e
            finally:
                ready.set()

        self._job_error = None
        self._job = threading.Thread(target=work, name=HELPER_THREAD, daemon=True)
        self._job.start()

    def extremes_ready(self) -> bool:
        """The background's extreme eigenvalues are known (or there is no background work)."""
        ready = getattr(self, "_ready", None)
        return ready is None or ready.is_set()

    def wait(self) -> None:
        """Wait for :meth:`start_background`'s thread; raise what it raised."""
        job = getattr(self, "_job", None)
        if job is None:
            return
        job.join()
        self._job = None
        if self._job_error is not None:
            raise self._job_error

    def metric_change(self, J0, w0, J1, w1, block: int = 6, iterations: int = 12, seed: int = 0) -> float:
        """‖F‖₂ estimated, F = U⁻ᵀ Nᵀ S⁻¹ (J1ᵀW1J1 − J0ᵀW0J0) S⁻¹ N U⁻¹: how far the normal matrix of (J1, w1)
        is from this one (of J0, w0) in its own metric. M1 = Uᵀ(I + F)U, so M1⁻¹ lies between M⁻¹/(1 + ‖F‖)
        and M⁻¹/(1 − ‖F‖): every variance, and the condition number's square, within that factor. Block Krylov
        (``block`` seeded vectors, then F applied to the newest block; Rayleigh-Ritz on the whole subspace: the
        largest |Ritz value|, never above ‖F‖ and never decreasing), stopped when a block raised it by under
        :data:`METRIC_SETTLED`. The whole subspace, not only the last block (power iteration), takes one or
        two products fewer for the same number: 4 at the SCARA's 1 deg grid, where power iteration took 5."""
        J0, J1 = J0.tocsr(), J1.tocsr()
        s = self.s[:, None]

        def apply(V):  # (two J products beside each other on a large J: they release the GIL)
            Z = self.to_full(triangular_solve(self._U, V)) / s  # (releases the GIL: threads)
            one, zero = in_parallel(*[lambda J=J, w=w: J.T @ (w[:, None] * (J @ Z)) for J, w in ((J1, w1), (J0, w0))],
                                    parallel=J0.nnz >= PARALLEL_NONZEROS)
            D = one - zero
            return triangular_solve(self._U, self.to_null(np.asarray(D) / s), transpose=True)

        V = np.linalg.qr(np.random.default_rng(seed).normal(size=(self.dim, min(block, self.dim))))[0]
        basis, images, estimate = [], [], 0.0
        for _ in range(iterations):
            basis.append(V)
            images.append(apply(V))
            Q, FQ = np.hstack(basis), np.hstack(images)
            T = Q.T @ FQ
            new = float(np.abs(np.linalg.eigvalsh(0.5 * (T + T.T))).max())
            settled, estimate = new - estimate <= METRIC_SETTLED * new, max(estimate, new)
            if settled or Q.shape[1] + V.shape[1] > self.dim:
                break
            R = images[-1] - Q @ (Q.T @ images[-1])
            R -= Q @ (Q.T @ R)  # (twice: orthogonal to working precision)
            V = np.linalg.qr(R)[0]
        return estimate

    # -- the null-space basis ------------------------------------------------------------------
    def _householder(self, As):
        """Pivoted QR of (A / s)ᵀ: the first r reflectors span the constraints' rows (r their rank)."""
        self.r = 0
        if not As.size:
            return
        qr, _, tau, _, _ = lapack.dgeqp3(np.asarray(As.T, order="F"))
        diag = np.abs(np.diag(qr))
        self.r = int(np.sum(diag > 1e-12 * max(diag.max(initial=0.0), 1e-300)))
        # The reflectors touch only the first r coordinates and those the constraints involve (a gauge row
        # names a few parameters): Q is the identity elsewhere, so it is applied to those rows only.
        below = np.tril(qr[:, :self.r], -1)
        self._rows = np.union1d(np.arange(self.r), np.flatnonzero(np.any(below != 0, axis=1)))
        self._qr, self._tau = np.asfortranarray(qr[self._rows, :self.r]), tau[:self.r].copy()

    def _apply_q(self, C, side: str, trans: str, overwrite: bool = False):
        """Q C, Qᵀ C (side L) or C Q, C Qᵀ (side R) with Q = [constraint rows | null-space basis N]; C itself
        is changed only with ``overwrite``."""
        C = np.asarray(C, dtype=float, order="F") if overwrite else np.array(C, dtype=float, order="F")
        if self.r == 0:
            return C
        rows = self._rows
        part = np.asfortranarray(C[rows, :] if side == "L" else C[:, rows])
        out, _, info = lapack.dormqr(side, trans, self._qr, self._tau, part, 64 * max(part.shape), overwrite_c=1)
        if side == "L":
            C[rows, :] = out
        else:
            C[:, rows] = out
        return C

    def basis(self) -> np.ndarray:
        """N (n, dim) explicit (dense path: as built; large: Q's last columns)."""
        if self._N is None:
            E = np.zeros((self.n, self.dim))
            E[self.r:] = np.eye(self.dim)
            self._N = self._apply_q(E, "L", "N", overwrite=True)
        return self._N

    def to_full(self, z) -> np.ndarray:
        """N z (z over the null space, (dim,) or (dim, k)) in the scaled coordinates."""
        if not self.large:
            return self._N @ z
        Z = np.zeros((self.n,) + np.shape(z)[1:], order="F")
        Z[self.r:] = z
        return self._apply_q(Z.reshape(self.n, -1), "L", "N", overwrite=True).reshape(Z.shape)

    def to_null(self, y) -> np.ndarray:
        """Nᵀ y (y in the scaled coordinates, (n,) or (n, k))."""
        if not self.large:
            return self._N.T @ y
        return self._apply_q(np.reshape(y, (self.n, -1)), "L", "T")[self.r:].reshape((self.dim,) + np.shape(y)[1:])

    # -- rank and conditioning -----------------------------------------------------------------
    def _eigh(self):
        if self._lam is None:
            self._lam, self._vec = np.linalg.eigh(self.M)
        return self._lam, self._vec

    def extremes(self):
        """(smallest, largest) eigenvalue of M (the smallest 0 when M is not positive definite: large path);
        computed once (waits for the background's, not for its variances)."""
        ready = getattr(self, "_ready", None)
        if ready is not None:
            ready.wait()
        if getattr(self, "_job_error", None) is not None:
            self.wait()  # (raises it)
        if self._extremes is None:
            self._extremes = self._compute_extremes()
        return self._extremes

    def _compute_extremes(self):
        # Up to DENSE_EXTREMES dimensions all eigenvalues cost less than ARPACK's setup (and ARPACK needs more
        # dimensions than eigenvalues asked for): a fit without uncertainty takes the large path at any size.
        if not self.large or self.dim <= DENSE_EXTREMES:
            lam = self._eigh()[0]
            return lam[0], lam[-1]
        from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigsh

        v0 = np.ones(self.dim)
        try:
            M = LinearOperator((self.dim, self.dim), matvec=self._times_M, dtype=float)
            top = eigsh(M, k=1, which="LA", v0=v0, tol=LANCZOS_TOLERANCE, return_eigenvectors=False)[0]
            if self._U is None:
                return 0.0, top
            inv = LinearOperator((self.dim, self.dim), matvec=self.solve, dtype=float)
            low = 1.0 / eigsh(inv, k=1, which="LA", v0=v0, tol=LANCZOS_TOLERANCE,
                             return_eigenvectors=False)[0]
        except ArpackNoConvergence:  # rare: the dense decomposition decides
            lam = self._eigh()[0]
            return lam[0], lam[-1]
        return low, top

    def clearly_regular(self, margin: float = 100.0) -> bool:
        """Large path: M is factorized and LAPACK's condition estimate (dpocon, O(dim²) from the factor) puts
        λ_min/λ_max above ``margin`` x :data:`RANK_TOLERANCE` -- full rank without Lanczos. False decides
        nothing (ask :meth:`deficient`): the estimate is of the 1-norm condition, cond₂ ≤ cond₁, but LAPACK's
        ‖M⁻¹‖₁ is estimated from below, within a small factor -- the margin."""
        if not self.factorized:
            return False
        L = np.abs(np.tril(self._packed, -1))
        anorm = float(np.max(L.sum(axis=0) + L.sum(axis=1) + np.abs(self._M_diag)))
        rcond, info = lapack.dpocon(self._U, anorm)
        return info == 0 and rcond > margin * RANK_TOLERANCE

    def deficient(self) -> bool:
        low, top = self.extremes()
        return bool(low < RANK_TOLERANCE * top) or not np.isfinite(top)

    def condition(self) -> float:
        """√(λ_max / λ_min) of M (the conditioning within the constraints), inf when rank deficient."""
        low, top = self.extremes()
        return float(np.sqrt(top / low)) if low > RANK_TOLERANCE * top else float("inf")

    def weak_names(self, names) -> list:
        """What M cannot determine: the parameters in its near-null space (none when positive definite)."""
        if not self._finite:
            return list(names)
        if self.large and not self.deficient():
            return []
        lam, vec = self._eigh()
        weak = lam < RANK_TOLERANCE * lam[-1]
        if not weak.any():
            return []
        # Each parameter's share of the near-null space: the row norms of its orthonormal basis -- the same
        # whatever basis the (near-degenerate) eigenvectors happen to take, so both paths name the same.
        mag = np.linalg.norm(self.basis() @ vec[:, np.flatnonzero(weak)], axis=1)
        return [names[i] for i in np.flatnonzero(mag > 0.1 * mag.max())]

    # -- solves and covariance -----------------------------------------------------------------
    def solve(self, z) -> np.ndarray:
        """M⁻¹ z (over the null space)."""
        if not self.large:
            return np.linalg.solve(self.M, z)
        if np.ndim(z) == 1:  # two BLAS triangular solves releasing the GIL (threads): the helper thread's Lanczos
            return triangular_solve(self._U, triangular_solve(self._U, z, transpose=True))  # and the solver run on
        x, _ = lapack.dpotrs(self._U, np.reshape(z, (self.dim, -1)), lower=0)
        return x.reshape(np.shape(z))

    def _factor_rows(self) -> np.ndarray:
        """K = (N U⁻¹) / s (n, dim): the covariance within the constraints is K Kᵀ (large path)."""
        if self._K is None:
            self._K = self.to_full(self._inverse_factor()) / self.s[:, None]
        return self._K

    def inverse_diagonal(self) -> np.ndarray:
        """diag((N/s) M⁻¹ (N/s)ᵀ): the variances within the constraints per unit σ²."""
        if not self.large:
            return np.diag(self.inverse())
        self.wait()
        if self._diag is None:
            self._diag = self._row_norms()
        return self._diag

    def _row_norms(self) -> np.ndarray:
        """diag(K Kᵀ), K = (N U⁻¹) / s, without forming K (large path): the reflectors touch only the rows
        ``_rows``, so every other row of N is a unit row and K's row is a row of U⁻¹; the few rows the
        constraints involve are formed from Q's (|rows|, |rows|) block."""
        single = self.dim > THOUSANDS  # (see INVERSE_RTOL)
        tail = self._inverse_row_norms(np.float32 if single else np.float64)
        if single and not self._row_norms_agree(tail):
            tail = self._inverse_row_norms(np.float64)
        d = np.zeros(self.n)
        d[self.r:] = tail
        if self.r:
            rows = self._rows
            E = np.zeros((self.n, len(rows)), order="F")
            E[rows, np.arange(len(rows))] = 1.0
            Q_rows = self._apply_q(E, "L", "N", overwrite=True)[rows]  # Q[rows, rows]
            free = rows >= self.r
            R = np.array([self._inverse_row(i) for i in rows[free] - self.r]).reshape(-1, self.dim)
            K_rows = Q_rows[:, free] @ R
            d[rows] = np.einsum("ij,ij->i", K_rows, K_rows)
        return d / self.s ** 2

    def _inverse_row_norms(self, dtype, chunk: int = 256) -> np.ndarray:
        """Σ_{j ≥ i} U⁻¹_ij² (dim,), U⁻¹ by LAPACK's triangular inverse in ``dtype``, squared and summed in
        float64 over the upper triangle (below the diagonal lie M's numbers, never read), ``chunk`` columns at a
        time: few long numpy calls, so a solver in another thread is not kept waiting for the GIL."""
        Uinv, _ = triangular_inverse(self._U, dtype)  # (releases the GIL: the solver's thread runs on)
        out = np.zeros(self.dim)
        for j0 in range(0, self.dim, chunk):
            j1 = min(self.dim, j0 + chunk)
            sq = np.square(Uinv[:j1, j0:j1], dtype=np.float64)
            sq[j0:] = np.triu(sq[j0:])  # the diagonal block: its upper triangle only
            out[:j1] += sq.sum(axis=1)
        return out

    def _row_norms_agree(self, norms, rows: int = 8) -> bool:
        """``norms`` (of a single-precision inverse) within :data:`INVERSE_RTOL` of the double-precision ones at
        ``rows`` rows spread over U⁻¹ (:meth:`_inverse_row`)."""
        for i in np.unique(np.linspace(0, self.dim - 1, rows).astype(int)):
            y = self._inverse_row(i)
            exact = float(y @ y)
            if not abs(norms[i] - exact) <= INVERSE_RTOL * exact:
                return False
        return True

    def _inverse_row(self, i: int) -> np.ndarray:
        """Row i of U⁻¹ in double precision: the solution of Uᵀ y = e_i (zero before i)."""
        e = np.zeros(self.dim)
        e[i] = 1.0
        return triangular_solve(self._U, e, transpose=True)

    def _inverse_factor(self) -> np.ndarray:
        """U⁻¹ (dim, dim), upper triangular (the factor's memory holds M below the diagonal: cleared)."""
        Uinv, _ = triangular_inverse(self._U, np.float64)
        for j in range(self.dim - 1):  # column by column: contiguous in Fortran order, no index arrays
            Uinv[j + 1:, j] = 0.0
        return Uinv

    def inverse(self) -> np.ndarray:
        """(N/s) M⁻¹ (N/s)ᵀ (n, n): the covariance within the constraints per unit σ²."""
        if not self.large:
            Ns = self._N / self.s[:, None]
            return Ns @ np.linalg.solve(self.M, Ns.T)
        K = self._factor_rows()
        return K @ K.T


# -- helpers -------------------------------------------------------------------------------------
class _StepProgram:
    """The LM step as a Drake program in the step δ = e − x: the Gauss-Newton model ½δᵀHdδ + gᵀδ, src's linear
    constraints and linear/quadratic costs shifted to δ (all costs but ``skip``: the data cost, which the
    model replaces). Built once per set of bindings; :meth:`at` updates its coefficients and bounds for
    the next x (Drake's UpdateCoefficients, set_bounds) instead of building a program per step."""

    def __init__(self, src, n, skip, key):
        from pydrake.solvers import (BoundingBoxConstraint, LinearConstraint, LinearCost, MathematicalProgram,
                                     QuadraticCost)

        self.key, self.prog = key, MathematicalProgram()
        self.d = d = self.prog.NewContinuousVariables(n, "delta")
        self.model = self.prog.AddQuadraticCost(np.eye(n), np.zeros(n), d, is_convex=True)
        self.constraints, self.costs = [], []
        for b in src.GetAllConstraints():
            e = b.evaluator()
            idx = src.FindDecisionVariableIndices(b.variables())
            if not isinstance(e, (LinearConstraint, BoundingBoxConstraint)):
                raise InputError(f"constraint {type(e).__name__} is not linear: use the 'nlp' solver")
            A = e.GetDenseA()
            eq = e.lower_bound() == e.upper_bound()
            # Equalities stay equalities, so Drake can pick its exact EqConstrainedQP solver.
            shifted = [(mask, self.prog.AddLinearEqualityConstraint(A[mask], np.zeros(mask.sum()), d[idx])
                        if equal else self.prog.AddLinearConstraint(A[mask], np.zeros(mask.sum()),
                                                                    np.zeros(mask.sum()), d[idx]))
                       for mask, equal in ((eq, True), (~eq, False)) if mask.any()]
            self.constraints.append((e, A, eq, idx, shifted))
        for b in src.GetAllCosts():
            e = b.evaluator()
            if e is skip:
                continue
            idx = src.FindDecisionVariableIndices(b.variables())
            if isinstance(e, QuadraticCost):
                self.costs.append((e, idx, self.prog.AddQuadraticCost(e.Q(), e.b(), d[idx], is_convex=True)))
            elif isinstance(e, LinearCost):
                self.costs.append((e, idx, self.prog.AddLinearCost(e.a(), 0.0, d[idx])))
            else:
                raise InputError(f"cost {type(e).__name__} is not linear or quadratic: use the 'nlp' solver")

    def at(self, x, Hd, g):
        """(program, δ variables) of the step at x; None when a constraint's coefficients (or which of its rows
        are equalities) changed since it was built: then build anew."""
        from pydrake.solvers import QuadraticCost

        self.model.evaluator().UpdateCoefficients(Hd, g, 0.0, True)
        for e, A, eq, idx, shifted in self.constraints:
            if not (np.array_equal(e.GetDenseA(), A) and np.array_equal(e.lower_bound() == e.upper_bound(), eq)):
                return None
            shift = A @ x[idx]
            lo, hi = e.lower_bound() - shift, e.upper_bound() - shift
            for mask, binding in shifted:
                binding.evaluator().set_bounds(lo[mask], hi[mask])
        for e, idx, binding in self.costs:
            if isinstance(e, QuadraticCost):
                Q = e.Q()
                binding.evaluator().UpdateCoefficients(Q, Q @ x[idx] + e.b(), 0.0, True)
            else:
                binding.evaluator().UpdateCoefficients(e.a(), 0.0)
        return self.prog, self.d


class _NormalOperator:
    """JᵀWJ as an operator (large path): products and the diagonal without forming the matrix."""

    def __init__(self, J, w):
        self.J, self.w = J.tocsr(), w
        self.JT = self.J.T.tocsr()

    def diagonal(self) -> np.ndarray:
        JT = self.JT  # Σ_k w_k J_ki²: a product of Jᵀ's squares (sharing its index arrays) with w
        return sp.csr_matrix((JT.data ** 2, JT.indices, JT.indptr), shape=JT.shape) @ self.w

    def __matmul__(self, v):
        return self.JT @ (self.w * (self.J @ v))


def _parallel(a, b, D) -> bool:
    """Whether steps a and b point the same way (cosine > :data:`PARALLEL_COSINE`), each coordinate scaled by
    √D (the normal matrix's diagonal: mm and µrad side by side)."""
    s = np.sqrt(np.maximum(D, 0.0))
    a, b = a * s, b * s
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return bool(na > 0 and nb > 0 and a @ b > PARALLEL_COSINE * na * nb)


def _pcg(apply, b, precondition, rtol=1e-10, max_iterations=100):
    """Preconditioned conjugate gradients for apply(x) = b (symmetric positive definite): (x, converged)."""
    x = np.zeros_like(b)
    norm_b = np.linalg.norm(b)
    if norm_b == 0:
        return x, True
    res = b.copy()
    z = precondition(res)
    p, rz = z.copy(), res @ z
    for _ in range(max_iterations):
        Ap = apply(p)
        alpha = rz / (p @ Ap)
        x += alpha * p
        res -= alpha * Ap
        if np.linalg.norm(res) <= rtol * norm_b:
            return x, True
        z = precondition(res)
        rz, rz_old = res @ z, rz
        p = z + (rz / rz_old) * p
    return x, False


def _normal_matrix(J, w) -> np.ndarray:
    """Dense JᵀWJ (w ≥ 0); through a dense J when it is narrow (sparse products cost more there). Wide: the
    columns that many rows touch (geometry, stations) as a dense block by BLAS; the rest (map nodes, a few per
    row) by a sparse product written straight into the result (one n x n array: at thousands of unknowns
    every extra one costs a pass and fresh pages) -- a sparse product would otherwise spend most of its time
    on the busy columns."""
    if J.shape[1] <= SMALL_PROBLEM:
        S = np.sqrt(w)[:, None] * J.toarray()
        return S.T @ S  # (numpy sees SᵀS: BLAS syrk, half the work of a general product, exactly symmetric)
    J = J.tocsr()
    n = J.shape[1]
    busy = np.bincount(J.indices, minlength=n) > J.shape[0] // 20
    if not busy.any() or busy.all():
        return (J.T @ sp.diags(w) @ J).toarray()
    dense = np.flatnonzero(busy)
    quiet = J.copy()
    quiet.data = quiet.data * np.repeat(np.sqrt(w), np.diff(J.indptr))  # √W J
    Jd = quiet[:, dense].toarray()
    quiet.data[busy[quiet.indices]] = 0.0  # the busy columns' entries out: the quiet ones keep their indices
    quiet.eliminate_zeros()
    H = np.zeros((n, n))
    cross = np.empty((n, len(dense)))  # (n, busy): the quiet rows, the busy rows 0 ...
    QT = quiet.T.tocsr()

    def rows(a, b):  # rows a:b of the quiet product, written straight into H (busy rows and columns stay 0)
        rows_QT = QT[a:b]
        (rows_QT @ quiet).toarray(out=H[a:b])
        cross[a:b] = rows_QT @ Jd

    # Two row blocks, each on a core for a large J (sparse products release the GIL), split where half of the
    # entries lie.
    half = int(np.searchsorted(QT.indptr, QT.indptr[-1] / 2))
    in_parallel(lambda: rows(0, half), lambda: rows(half, n), parallel=J.nnz >= PARALLEL_NONZEROS)
    cross[dense] = Jd.T @ Jd  # ... and take the busy block
    H[:, dense] = cross
    H[dense, :] = cross.T
    return H


def _leading_block(A, r: int) -> np.ndarray:
    """A[r:, r:] of a Fortran-ordered square A, moved to the front of A's own memory (A is destroyed): the
    block as a Fortran-contiguous view, without a second n x n array. Column j moves down to offset j·m; the
    source lies at or after the destination, so copying forward never overwrites what is still to be read."""
    n = A.shape[0]
    if r == 0:
        return A
    m = n - r
    flat = A.reshape(-1, order="F")
    for j in range(m):
        src = (r + j) * n + r
        flat[j * m:(j + 1) * m] = flat[src:src + m]
    return flat[:m * m].reshape((m, m), order="F")


def _step_fraction_decrease(cost: float, dof: int) -> float:
    """½ f² σ̂² with σ̂² = 2·cost / dof (f = :data:`STEP_FRACTION`): the predicted decrease below which no
    Gauss-Newton step moves a parameter by f of its u (:meth:`LeastSquaresProgram._negligible_decrease`); 0
    without redundant readings (dof ≤ 0)."""
    return STEP_FRACTION ** 2 * cost / dof if dof > 0 else 0.0


def _factor_threads(dim: int):
    """BLAS threads for the n³ Cholesky factorization of ``dim`` unknowns: as many as the process started with
    above :data:`THOUSANDS` unknowns when no helper thread (:meth:`Within.start_background`) is at work --
    blocks of thousands keep every thread busy (4 123 unknowns: 0.51 s on one thread, 0.31 s on two) --, else
    the caller's (one, in :meth:`LeastSquaresProgram.fit`: below that, threads only cost)."""
    import contextlib
    import threading

    helper = any(t.name == HELPER_THREAD and t.is_alive() for t in threading.enumerate())
    return blas_threads() if dim > THOUSANDS and not helper else contextlib.nullcontext()


def _round_up(v: float, digits: int = 2) -> float:
    """v > 0 rounded up to ``digits`` significant digits (a stated bound is not understated by rounding)."""
    if not v > 0:
        return 0.0
    e = 10.0 ** (np.floor(np.log10(v)) - digits + 1)
    return float(np.ceil(v / e - 1e-9) * e)


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


def _outlier_listing(out, most=12) -> str:
    """'line 12 (+8.1 sigma), ...' of reading labels with ``normalized`` (largest first)."""
    def where(o):
        label = f"line {o['line']}" if "line" in o else f"reading {o.get('row', '?')}"
        return f"{label} ({o['normalized']:+.1f} sigma)"
    return ", ".join(where(o) for o in out[:most]) + (f" and {len(out) - most} more" if len(out) > most else "")


def _listing(names, most=8) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


#: The reading uncertainty a prior is weighed against when neither a budget nor the readings tell it (fewer than
#: 10 % spare readings: :meth:`LeastSquaresProgram.reading_sigma`), mm: a laser tracker's or interferometer's
#: order in a robot cell.
UNKNOWN_READING_MM = 0.01


class Calibration(LeastSquaresProgram):
    """The calibration program of a measurement (see the module docstring), units of the measurement (mm, deg).

    ``gauge``: an object with ``A``, ``b`` (A x = b over the measurement's names) and ``sentence``
    (e.g. :func:`olti_drake.model.serial.find_gauge`'s), or None. ``source``: what the readings came from,
    for the messages. Build, optionally add to :attr:`prog`, then :meth:`fit` (or ``Solve(prog)``).
    """

    def __init__(self, measurement, options: SolverOptions = None, gauge=None, source: str = "campaign"):
        self.measurement = measurement
        self._source = source
        self._declare(list(measurement.names), options or SolverOptions())
        self.x0 = measurement.start_vector()
        self.gauge = "none"
        if gauge is not None:
            self.prog.AddLinearEqualityConstraint(np.asarray(gauge.A, float), np.asarray(gauge.b, float),
                                                  self.variables).evaluator().set_description("gauge")
            self.gauge = gauge.sentence
        ties = getattr(measurement, "ties", None)
        A, tied, targets = ties() if ties is not None else (np.zeros((0, len(self.names))), [], [])
        if len(tied):  # map nodes beyond the readings: no parameters (the model's ties, issue 23)
            self.prog.AddLinearEqualityConstraint(A, np.zeros(len(A)), self.variables).evaluator().set_description(
                "map nodes beyond the readings")
            self.notes.append(f"map nodes the readings barely reach in a direction (less than one pose's weight) are "
                              f"no parameters, {len(tied)} of them: " + "; ".join(
                                  f"{t} follows {w}" for t, w in list(zip(tied, targets))[:6])
                              + (f"; and {len(tied) - 6} more" if len(tied) > 6 else ""))
            self.tied = list(tied)
        if hasattr(measurement, "residual_rows"):  # batched residuals: the Monte Carlo's fast path (uncertainty)
            self.residual_rows = measurement.residual_rows

    @property
    def source(self) -> str:
        return self._source

    #: The shipped budget (io.budget.default_budget: "scara" 000 Table 2, "machine" 001 Table 4) whose reading u the
    #: residuals are judged against when the options and the solve name none; None: the readings' own.
    budget_kind = None

    def default_budget(self):
        """The budget given to the kind's solve, else the shipped one of :attr:`budget_kind` (None without one)."""
        from olti_drake.io.budget import default_budget

        given = getattr(self, "_solve_budget", None)
        return given or (default_budget(self.budget_kind) if self.budget_kind else None)

    #: The campaign's columns (arrays of ``self.data``, one value per reading) that name a reading to the user in
    #: its outlier listing: its file line first. Empty: the kind names its readings itself, or by row.
    reading_keys = ()

    def reading_label(self, k: int) -> dict:
        if not self.reading_keys:
            return super().reading_label(k)
        return {key: int(getattr(self.data, key)[k]) for key in self.reading_keys}

    def implausible(self, x) -> list:
        """The measurement's (its stations, its position model's values) physically impossible values of x."""
        check = getattr(self.measurement, "implausible", None)
        return check(np.asarray(x, dtype=float)) if check is not None else []

    def residuals(self, x):
        return self.measurement.residuals(np.asarray(x, dtype=float))

    def beam_lengths(self, x, residuals=None) -> np.ndarray:
        return self.measurement.beam_lengths(np.asarray(x, dtype=float), residuals)

    def layout(self, v, uncertainty: bool = False) -> dict:
        return self.measurement.layout(np.asarray(v, dtype=float), uncertainty)

    def roughness(self):
        rows = getattr(self.measurement, "roughness", None)
        return rows() if rows is not None else None

    def roughness_groups(self):
        groups = getattr(getattr(self.measurement, "model", None), "roughness_groups", None)
        return groups() if groups is not None else None



def station_fit(points_mm, readings_mm, start_mm=None):
    """(P, L0) of one station from known points p (K, D), D = 2 or 3, and readings d = ‖p − P‖ − L0 (K,), mm.

    Without a start: the linearized multilateration ‖p‖² − 2p·P + ‖P‖² =
    (d + L0)² is linear in (P, L0, ‖P‖² − L0²); then Gauss-Newton on Eq. (3)
    of 001 (Eq. (5) of 000 for a SCARA reflector; the 3D station of an N-joint robot).
    """
    p, d = np.asarray(points_mm, dtype=float), np.asarray(readings_mm, dtype=float)
    D = p.shape[1]
    if np.linalg.matrix_rank(p - p.mean(axis=0), tol=1e-9 * max(1.0, np.abs(p).max())) < D:
        raise ValueError(f"the points lie on one {'line' if D == 2 else 'plane'}: distances cannot tell the two "
                         f"sides of it apart")
    if start_mm is None:
        A = np.column_stack([-2 * p, -2 * d, np.ones(len(d))])
        sol, *_ = np.linalg.lstsq(A, d ** 2 - np.sum(p ** 2, axis=1), rcond=None)
        P, L0 = sol[:D], sol[D]
    else:
        P = np.asarray(start_mm, dtype=float)
        L0 = np.mean(lengths(p - P) - d)
    try:
        with np.errstate(invalid="ignore", divide="ignore"):
            for _ in range(20):
                diff = p - P
                dist = lengths(diff)  # (= np.hypot.reduce bit for bit, faster)
                J = np.column_stack([-diff / dist[:, None], -np.ones(len(d))])
                # D + 1 unknowns, the points spread (checked above): the normal equations, ~5x cheaper than lstsq.
                step = np.linalg.solve(J.T @ J, -(J.T @ (dist - L0 - d)))
                P, L0 = P + step[:D], L0 + step[D]
                if np.max(np.abs(step)) < 1e-12:
                    break
        if not (np.all(np.isfinite(P)) and np.isfinite(L0)):
            raise np.linalg.LinAlgError("no finite solution")
    except np.linalg.LinAlgError:
        raise StationFitFailed(_station_fit_cause(p, d)) from None
    return P, L0


def station_starts(points_mm, readings_mm, station, labels, source: str):
    """(P (N, D), L0 (N,)) mm: :func:`station_fit` of every station ``labels[j]`` to the readings whose ``station``
    is that label, at their (nominal) points; a station it cannot place is not identifiable, named (its P_j)."""
    p, d, station = np.asarray(points_mm, float), np.asarray(readings_mm, float), np.asarray(station)
    P, L0 = [], []
    for j, label in enumerate(labels):
        sel = station == label
        try:
            s, l0 = station_fit(p[sel], d[sel])
        except ValueError as e:
            raise UnidentifiableError(f"{source}: station {label}: not identifiable: P{j}_x_mm, P{j}_y_mm, "
                                      f"P{j}_z_mm ({e})", [f"P{j}_x_mm"]) from None
        P.append(s)
        L0.append(l0)
    return np.array(P), np.array(L0)


class StationFitFailed(ValueError):
    """:func:`station_fit` found no station: the readings are no distances from one point to these points (the
    message says why it looks so), not a flat point set (that is a plain ValueError)."""


def _station_fit_cause(p, d) -> str:
    """Why readings d (K,) are no distances ‖p − P‖ − L0 from the points p (K, D), mm: the unit, or the sign."""
    spread, extent = float(np.ptp(d)), float(np.ptp(p, axis=0).max())
    if spread < 1e-2 * extent:
        return (f"the readings spread {spread:.4g} mm while the points they are read at spread {extent:.4g} mm: "
                f"readings in another unit (metres?), not mm")
    return ("no station position fits the readings (the fit of ||p - P|| - L0 met a singular step): readings "
            "whose sign is flipped (they must grow as the beam lengthens), of another station, or at other "
            "targets than numbered")


def _norms(diff) -> np.ndarray:
    """Row lengths; np.hypot in 2D (the arithmetic the SCARA and machine results were written with)."""
    return np.hypot(*diff.T) if diff.shape[1] == 2 else np.linalg.norm(diff, axis=1)
