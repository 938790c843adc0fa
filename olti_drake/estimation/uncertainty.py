"""Uncertainty of identified parameters and predictions (000 §5, 001 §4.4).

Two methods from one reading-error model built from a budget (000 Table 2,
001 Table 4):

* **linear** (JCGM 100, the Jacobian method 000 §5 Remark names): the
  sensitivity of the least-squares solution to every reading, within the
  gauge and other equality constraints, propagates the per-reading variances.
* **mc** (JCGM 101): draw every reading's error from the budget, re-solve the
  nonlinear problem (10), collect the estimates. Trials are solved in batches:
  the exact gradient J(x)ᵀr(x) of every trial with the Hessian factorized once
  at the solution -- a chord iteration that converges to each trial's own
  least-squares solution; a trial it does not converge, Gauss-Newton at the trial's own point -- over worker processes: this machine's cores or a cluster's
  (:func:`olti_drake.estimation.trials.run_trials`, joblib: loky, Dask, Ray).

Reading errors (per reading k at reflector distance D_k):
``reading`` contributors add along the beam; ``pose`` contributors displace
the laser head isotropically, so their along-beam part adds; ``beam_direction``
contributors tilt the beam by ψ, which shortens the reading by D ψ²/2 (the
cosine error). Units: mm and degrees; angles of the budget in rad.
"""

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import FitRefused
from olti_drake.model.budget import Budget, ReadingErrors
from olti_drake.model.propagation import predicted_std
from olti_drake.estimation.trials import TrialTask, effective_workers, run_trials

#: Trials per batch: the unit of seeding (reproducible whatever the worker count) and of progress.
BATCH = 250
#: Batches per round of the adaptive procedure (at least; more when the coverage probability needs them):
#: fixed, so adaptive results do not depend on the workers.
ROUND_BATCHES = 4
#: Fewest blocks that ``workers=None`` sends to worker processes (fewer run in this process).
MIN_PARALLEL_BLOCKS = 4
#: Default cap on the trials of the adaptive procedure (``olti uncertainty --max-trials``).
MAX_TRIALS = 50_000


def trials_for_intervals(coverage: float) -> int:
    """JCGM 101 §7.2.2: M large compared with 1/(1 − p), e.g. 10^4/(1 − p) trials for a coverage interval
    (200 000 for p = 0.95); fewer give intervals whose endpoints are not reliable."""
    return int(np.ceil(1e4 / (1.0 - coverage) - 1e-6))


def round_trials(coverage: float) -> int:
    """Trials per adaptive round: at least :data:`ROUND_BATCHES` batches and J = 100/(1 − p) (JCGM 101 §7.9.4 b),
    in whole batches."""
    need = max(ROUND_BATCHES * BATCH, int(np.ceil(100.0 / (1.0 - coverage) - 1e-6)))
    return BATCH * int(np.ceil(need / BATCH))


def _solution_map(ident, x):
    """B (n, n) with δx = −B g for a gradient g: the constrained Gauss-Newton step at x."""
    r, J = ident.residuals(x)
    return _constrained_inverse(J, ident.quadratic_costs()[0], ident.within, len(x)), J


def _constrained_inverse(J, Q_all, within, n):
    """(JᵀJ + Q) within the program's equalities, inverted, the parameters' (n, n) block: ``Q_all`` over all
    decision variables (a user's own follow the parameters; the readings move only the parameters), ``within``
    H → :class:`~olti_drake.estimation.calibration.Within`."""
    m = len(Q_all) - n
    return within(np.pad((J.T @ J).toarray(), ((0, m), (0, m))) + Q_all).inverse()[:n, :n]


class _Remap:
    """The Gauss-Newton inverse at a trial's own point (:func:`_rescue`), from what travels with the trials:
    the equalities (A, rows over all variables) and all quadratic costs, not the program (a Drake
    MathematicalProgram does not pickle)."""

    def __init__(self, ident):
        from olti_drake.estimation.calibration import Within

        self.Q_all = np.asarray(ident.quadratic_costs()[0], float)
        self.A = ident._equality_rows()[0]
        self.large = ident._large()
        self._within = Within

    def __call__(self, J, n):
        return _constrained_inverse(J, self.Q_all, lambda H: self._within(H, self.A, large=self.large), n)


#: Gauss-Newton steps (each at the trial's own point) for a trial the chord iteration did not converge.
RESCUE_ITERATIONS = 30


def _rescue(remap, xt, residual, q, Q, tol):
    """A trial the chord iteration (B fixed at the estimate) did not converge, re-solved by Gauss-Newton at
    its own point: where the trial lies far enough along a weakly determined, curved direction, B H(x_t)
    has an eigenvalue near 2 and the chord steps stop shrinking; fresh normal equations do not.
    ``residual(xt)`` -> (r against the trial's readings, J). Its solution (same objective, same
    constraints) or None."""
    for _ in range(RESCUE_ITERATIONS):
        r, J = residual(xt)
        step = (J.T @ r + Q @ xt + q) @ remap(J, len(xt))
        xt = xt - step
        size = np.max(np.abs(step) / tol)
        if not np.isfinite(size):
            return None
        if size < 1.0:
            return xt
    return None


def linear_covariance(ident, x, errors: ReadingErrors) -> np.ndarray:
    """Covariance (n, n) of the parameters by linear propagation (JCGM 100; 000 §5 Remark, 001 §4.4).

    ``ident``: any :class:`~olti_drake.estimation.calibration.LeastSquaresProgram`
    (SCARA identification or multilateration).

    x = argmin ½‖r(x) − d‖² within the constraints gives dx/dd = B Jᵀ, so
    cov = B Jᵀ diag(u_k²) J B with u_k from the budget at each reading's distance.
    """
    B, J = _solution_map(ident, x)
    u2 = errors.std(ident.beam_lengths(x)) ** 2
    JtUJ = (J.T @ sp.diags(u2) @ J).toarray()
    return B @ JtUJ @ B


@dataclass
class MonteCarlo:
    """Monte Carlo samples (trials, n) of the parameters and how they were made."""

    samples: np.ndarray
    seed: int
    #: Adaptive: every estimate, standard uncertainty and coverage-interval endpoint stable (JCGM 101 §7.9.4),
    #: whether or not the run also reached the cap. Fixed trials: True (nothing to converge).
    converged: bool = True
    batches: int = 0
    notes: list = field(default_factory=list)
    #: The coverage intervals of probability ``coverage`` are reliable: enough trials (§7.2.2) or stable (§7.9).
    intervals_adequate: bool = False
    coverage: float = 0.95


def _mc_work(work):
    """What a Monte Carlo worker builds once: the fixed part of every trial (``work``, as it arrived)."""
    return work


def content_order(d_true, distance) -> np.ndarray:
    """(n,) the readings in an order set by their content, not by the campaign's rows: by beam length, then the
    model's own readings at the estimate (``d_true`` (K,) mm, K = per · n rows: a tracker point's x, y, z
    together), each rounded to 1 nm so that the estimate of the same campaign in another row order (equal to
    rounding) sorts the same. Ties are identical readings, whose errors may be swapped without changing the
    least-squares solution."""
    n = len(distance)
    keys = np.column_stack([np.asarray(distance, float).reshape(n, 1),
                            np.asarray(d_true, float).reshape(n, -1)])
    return np.lexsort(np.round(keys * 1e6).T[::-1])


def draw_by_content(errors, rng, distance, d_true, size: int) -> np.ndarray:
    """(size, K) reading errors in the campaign's rows, drawn in :func:`content_order` (a Monte Carlo of the same
    campaign in another row order draws the same error for the same reading); ``errors`` that order their rows
    themselves (``ordered_by_content``) draw as they are."""
    n, K = len(distance), np.size(d_true)
    if getattr(errors, "ordered_by_content", False) or n == 0 or K % n:
        return errors.draw(rng, distance, size)  # (no per-reading layout to order by)
    order = content_order(d_true, distance)
    drawn = errors.draw(rng, np.asarray(distance)[order], size)
    per = drawn.shape[1] // len(distance)
    E = np.empty_like(drawn)
    E[:, (per * order[:, None] + np.arange(per)).ravel()] = drawn
    return E


def _mc_block(w, seed, size: int):
    """One block of ``size`` trials: the readings' errors drawn from ``seed`` (the block's own) in an order set
    by the readings' content (:func:`draw_by_content`: results do not depend on the campaign's row order), each
    trial re-solved. The unit of seeding and of the batched solver: blocks of :data:`BATCH` whatever the
    workers."""
    E = draw_by_content(w["errors"], np.random.default_rng(seed), w["distance"], w["d_true"], size)
    if w["scatter"] is None:
        return _solve_trials_one_by_one(w["ident"], w["x"], w["B"], w["d_true"] + E, w["q"], w["Q"], tol=w["tol"],
                                        remap=w.get("remap"))
    return _solve_trials(w["ident"], w["x"], w["B"], w["d_true"] + E, w["q"], w["Q"], w["scatter"], tol=w["tol"],
                         remap=w.get("remap"))


def _travelling_program(ident):
    """What of ``ident`` the trials evaluate, in a form that can travel to worker processes: a
    :class:`~olti_drake.estimation.calibration.Calibration`'s residuals (and batched ``residual_rows``) are its
    measurement's, which pickles (its Drake plant rebuilt in the worker: SerialChain); the program itself holds a
    Drake MathematicalProgram, which does not. Any other program travels as itself."""
    from olti_drake.estimation.calibration import Calibration

    measurement = getattr(ident, "measurement", None)
    return measurement if measurement is not None and type(ident).residuals is Calibration.residuals else ident


#: The most chord iterations a Monte Carlo trial takes to converge (then refused as not converging).
TRIAL_ITERATIONS = 100
#: A Monte Carlo trial of a result re-solved on its campaign converges below this share of each parameter's u.
TRIAL_TOLERANCE_U = 1e-6


def trial_tolerance(fit) -> np.ndarray:
    """The per-parameter convergence tolerance (:func:`_tolerance`) of Monte Carlo trials about ``fit``:
    :data:`TRIAL_TOLERANCE_U` of each u, not below 1e-13 of the largest |x| -- one absolute tolerance for stations
    of 500 mm and angles in µrad would sit below the µrad parameters' rounding floor."""
    return np.maximum(TRIAL_TOLERANCE_U * np.asarray(fit.std, float), 1e-13 * max(1.0, float(np.max(np.abs(fit.x)))))


def _tolerance(x, tol=None):
    """The convergence tolerance of a trial's steps: ``tol`` (scalar or per parameter (n,), in the parameters'
    units) or by default 1e-13 of the largest |x| (at least 1e-13)."""
    return 1e-13 * max(1.0, np.max(np.abs(x))) if tol is None else np.asarray(tol, float)


def _solve_trials_one_by_one(ident, x, B, D, q, Q, max_iter=TRIAL_ITERATIONS, tol=None, remap=None):
    """:func:`_solve_trials` for a program without batched residuals (e.g. a
    :class:`~olti_drake.estimation.calibration.Calibration`): the same chord iteration on the exact gradient,
    trial by trial (each stops at its own convergence). Here a trial's row of D is r(x̂) + its errors, so that
    its residual r(x) − D is the model's reading at x minus the trial's reading. The first iteration, at x̂
    where r and J are known, is one product for all trials. The iteration converges linearly: once the
    last two steps shrink by a rate ρ < 0.1 and the steps still to come (|step| ρ / (1 − ρ)) sum below a
    tenth of the tolerance, the trial is converged without one more evaluation (each costs a forward
    kinematics of the campaign). Step sizes are measured in units of the tolerance (:func:`_tolerance`). A
    trial not converged in ``max_iter``: Gauss-Newton at its own point with ``remap`` (:func:`_rescue`)."""
    out = np.full((len(D), len(x)), np.nan)
    tol = _tolerance(x, tol)
    r, J = ident.residuals(x)
    first = x - ((r - D) @ J + x @ Q + q) @ B  # Q symmetric: (Q x)ᵀ = xᵀ Q
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for t, d in enumerate(D):
            xt = first[t].copy()
            previous = np.max(np.abs(first[t] - x) / tol)
            for _ in range(max_iter - 1):
                r, J = ident.residuals(xt)
                step = (J.T @ (r - d) + Q @ xt + q) @ B
                xt -= step
                size = np.max(np.abs(step) / tol)
                if not size >= 1.0:  # converged, or NaN (stays NaN below)
                    break
                rate = size / previous
                if rate < 0.1 and size * rate / (1.0 - rate) < 0.1:
                    size = 0.0  # what is left is below the tolerance by the observed contraction
                    break
                previous = size
            if size < 1.0:
                out[t] = xt
            elif remap is not None:
                def residual(z, d=d):
                    r, J = ident.residuals(z)
                    return r - d, J
                xt = _rescue(remap, xt if np.all(np.isfinite(xt)) else first[t].copy(), residual, q, Q, tol)
                if xt is not None:
                    out[t] = xt
    return out


def _solve_trials(ident, x, B, D, q, Q, scatter, max_iter=TRIAL_ITERATIONS, tol=None, remap=None):
    """Each row of D is a trial's readings; return each trial's least-squares solution (T, n).

    Chord iteration on the exact gradient: X ← X − (J(X)ᵀ r(X) + prior gradient) B. A trial whose last
    step is not below the tolerance after ``max_iter`` iterations (or not finite) did not converge: its
    row is NaN, for :func:`monte_carlo` to refuse. The iteration contracts linearly, at the rate the
    problem's curvature beside its information sets: a tolerance of 1e-6 u at a rate of 0.65 takes ~32
    iterations (a five-axis campaign with its linear axes identified on 6 knot intervals). ``remap``
    (:class:`_Remap`): a trial not converged is re-solved by Gauss-Newton at its own point (:func:`_rescue`)
    before it is given up.
    """
    X = np.tile(x, (len(D), 1))
    tol = _tolerance(x, tol)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging trial is caught below, not warned about
        for _ in range(max_iter):
            r, _, vals = ident.residual_rows(X, D)
            G = (r[..., None] * vals).reshape(len(X), -1) @ scatter + X @ Q + q
            step = G @ B
            X -= step
            last = np.max(np.abs(step) / tol, axis=1)
            if np.max(last) < 1.0:
                break
        for t in np.flatnonzero(~(last < 1.0)) if remap is not None else ():
            def residual(z, d=D[t]):
                return ident.residual_rows(z[None], d)[0][0], ident.residuals(z)[1]
            xt = _rescue(remap, X[t] if np.all(np.isfinite(X[t])) else x.copy(), residual, q, Q, tol)
            if xt is not None:
                X[t], last[t] = xt, 0.0
    X[~(last < 1.0)] = np.nan  # also catches NaN steps
    return X


def monte_carlo(ident, x, errors: ReadingErrors, trials: int = 1000, seed: int = 0, workers: Optional[int] = None,
                adaptive: bool = False, tolerance_digits: int = 2, max_trials: int = MAX_TRIALS,
                progress: Optional[Callable[[int, int], None]] = None, coverage: float = 0.95,
                tolerance=None, backend: str = "loky", scheduler=None) -> MonteCarlo:
    """JCGM 101 Monte Carlo of a least-squares estimate (000 §5; 001 §4.4).

    ``ident``: any :class:`~olti_drake.estimation.calibration.LeastSquaresProgram` with
    batched residuals ``residual_rows(X (T, n), readings (K,) or (T, K)) ->
    (r (T, K), cols (K, m), vals (T, K, m))`` -- the SCARA
    :class:`~olti_drake.estimation.identification.Identifier` or the
    :class:`~olti_drake.estimation.multilateration.Multilateration` of 001; a program without them (a
    :class:`~olti_drake.estimation.calibration.Calibration` of an N-joint robot) is solved trial by trial
    on its ``residuals`` (:func:`_solve_trials_one_by_one`), with the same semantics.

    Readings are the model's own at x plus errors drawn from the budget, so
    the trials scatter around x. ``trials`` fixed, or with ``adaptive`` rounds
    of :func:`round_trials` trials until, for every parameter, the estimate, the
    standard uncertainty and both endpoints of the ``coverage`` interval are
    stable to the tolerance of ``tolerance_digits`` significant digits of the
    standard uncertainty (JCGM 101 §7.9.4), or ``max_trials`` are done
    (then not converged, said in the notes). Batches of :data:`BATCH` trials
    have their own seeds (from ``seed``): results do not depend on ``workers``, ``backend`` (loky, dask,
    ray) or ``scheduler``, where the blocks run (:func:`olti_drake.estimation.trials.run_trials`; ``workers``
    None: up to 2 cores here from :data:`MIN_PARALLEL_BLOCKS` blocks on, else -- or when the program cannot
    travel -- this process). ``tolerance``: a trial's
    convergence tolerance, scalar or per parameter (:func:`_tolerance`; e.g. a small share of each parameter's u
    where parameters of very different units meet); default the program's own ``trial_tolerance`` when it
    states one.
    """
    if trials < 2:
        raise InputError(f"trials must be >= 2, got {trials}")
    if adaptive and max_trials < 2 * round_trials(coverage):
        raise InputError(f"max_trials must be >= {2 * round_trials(coverage)} (two adaptive rounds), got {max_trials}")
    _check_sample_size(max_trials if adaptive else trials, len(x), "max_trials" if adaptive else "trials")
    B, J = _solution_map(ident, x)
    distance = ident.beam_lengths(x)
    Q, q = ident.quadratic_costs()
    Q, q = Q[:len(x), :len(x)], q[:len(x)]  # priors on the parameters (a user's own variables: in B)
    if hasattr(ident, "residual_rows"):
        # The residuals against zero readings are the model's own readings at x: no campaign layout needed.
        model, cols, _ = ident.residual_rows(x[None], np.zeros(distance.size))
        k, m = cols.shape
        scatter = sp.csr_matrix((np.ones(k * m), (np.arange(k * m), cols.ravel())), shape=(k * m, len(x)))
    else:  # trials one by one on ident.residuals; the trial's readings relative to the campaign's
        model, scatter = ident.residuals(x)[0][None], None
    remap = _Remap(ident) if hasattr(ident, "_equality_rows") else None
    work = dict(ident=ident, x=x, B=B, errors=errors, distance=distance, d_true=model[0], q=q, Q=Q, scatter=scatter,
                remap=remap,
                tol=getattr(ident, "trial_tolerance", None) if tolerance is None else tolerance)
    task = TrialTask(_mc_work, dict(work, ident=_travelling_program(ident)), _mc_block, local=work)
    if workers is None and backend == "loky" and not adaptive and trials < MIN_PARALLEL_BLOCKS * BATCH:
        workers = 1  # a few blocks: starting the workers (seconds: imports, the problem) costs more than they gain
    if workers is None and effective_workers(None) > 1 and backend == "loky":
        try:
            task.portable()
        except InputError:  # a program that cannot travel runs here unless workers are asked for
            workers = 1
    seeds = np.random.SeedSequence(seed)  # rounds continue it: the blocks' seeds do not depend on the workers
    out, batches, done = [], 0, 0
    history, stable = [], False
    while True:
        n = trials if not adaptive else round_trials(coverage)
        sizes = [min(BATCH, n - i) for i in range(0, n, BATCH)]

        def report(k, _, first=done, sizes=sizes):
            if progress:
                progress(first + sum(sizes[:k]), trials if not adaptive else max_trials)

        out.extend(run_trials(task, len(sizes), seeds, workers=workers, backend=backend, scheduler=scheduler,
                              args=sizes, progress=report))
        done += n
        batches += len(sizes)
        if not adaptive:
            break
        history.append(_round_summary(np.vstack(out[-len(sizes):]), coverage))
        stable = len(history) >= 2 and _stable(history, tolerance_digits)
        if stable or done + n > max_trials:
            break
    samples = np.vstack(out)
    failed = int(np.isnan(samples).any(axis=1).sum())
    if failed:
        raise FitRefused(f"{ident.source}: Monte Carlo refused, nothing written -- {failed} of {len(samples)} trials "
                         f"did not converge to their own least-squares solution (the budget's errors drive the "
                         f"problem beyond where it can be re-solved from the estimate: check the budget's units)")
    notes = []
    if adaptive:
        notes.append(f"adaptive (JCGM 101 §7.9): {done} trials in {len(history)} rounds; " + (
            f"estimates, standard uncertainties and {coverage:g} coverage-interval endpoints stable to "
            f"{tolerance_digits} significant digit(s) of u" if stable else
            f"NOT stable to {tolerance_digits} significant digit(s) of u when the cap of {max_trials} trials "
            f"was reached"))
    adequate = stable if adaptive else done >= trials_for_intervals(coverage)
    return MonteCarlo(samples, seed, stable or not adaptive, batches, notes, adequate, coverage)


#: Largest array of Monte Carlo samples (trials x parameters, float64) a run may keep, bytes: beyond it a slip (a
#: trial count with too many zeros) would take the machine's memory, or run for days, before failing.
MAX_SAMPLE_BYTES = 4 * 2 ** 30


def _check_sample_size(trials: int, n: int, option: str) -> None:
    """Refuse, before any work, a run whose samples (trials x n doubles) exceed :data:`MAX_SAMPLE_BYTES`."""
    size = 8.0 * trials * n
    if size > MAX_SAMPLE_BYTES:
        raise InputError(f"{option} {trials}: the Monte Carlo samples of {n} parameters would take "
                         f"{size / 2 ** 30:.3g} GiB (at most {MAX_SAMPLE_BYTES / 2 ** 30:g} GiB, i.e. "
                         f"{int(MAX_SAMPLE_BYTES // (8 * n))} trials); use fewer trials")


def _round_summary(samples, coverage) -> np.ndarray:
    """(4, n) of one adaptive round: estimate (mean), standard uncertainty, low and high coverage endpoints."""
    lo, hi = np.percentile(samples, [50 * (1 - coverage), 50 * (1 + coverage)], axis=0)
    return np.array([samples.mean(axis=0), samples.std(axis=0, ddof=1), lo, hi])


def _stable(history, digits) -> bool:
    """JCGM 101 §7.9.4: for the estimate, u and both interval endpoints, 2·s of the round values (standard
    deviation of their mean over h rounds) ≤ δ = ½·10^l, δ the numerical tolerance of ``digits``
    significant digits of u."""
    H = np.array(history)  # (h, 4, n)
    u = H[:, 1].mean(axis=0)
    s = H.std(axis=0, ddof=1) / np.sqrt(len(H))
    l = np.floor(np.log10(np.maximum(u, 1e-300))) - (digits - 1)
    return bool(np.all(2 * s <= 0.5 * 10.0 ** l))


def prediction_std(ident, cov, x, commands) -> np.ndarray:
    """Standard uncertainty (N, 2) mm of predicted x, y at commanded poses (linear, k = 1).

    The robot block of the parameter covariance through the kinematic
    Jacobian: in the result's gauge frame (000 Eq. 3, 7).
    """
    n = ident.n_robot
    model = ident.robot0.with_parameters(x[:n])
    _, jx, jy = model.positions_and_jacobian(commands)
    C = cov[:n, :n]
    return np.column_stack([predicted_std(j, C) for j in (jx, jy)])


def uncertainty_dict(ident, std, method: str, budget: Budget, k: float = 2.0, samples=None,
                     coverage: float = 0.95, extra=None, intervals: bool = True) -> dict:
    """The ``uncertainty`` object of formats.md: result keys and shapes, standard uncertainties (k = 1).

    ``ident``: the program the uncertainties belong to (its :meth:`layout` gives the keys).
    Adds ``expanded`` (the same layout times ``k``) and, for Monte Carlo with
    ``intervals`` (enough trials, :attr:`MonteCarlo.intervals_adequate`), the
    probabilistically symmetric ``coverage_interval`` of probability ``coverage``.
    """
    from olti_drake.formats import UNCERTAINTY

    out = {"format": UNCERTAINTY, "method": method, "k": 1}
    out.update(ident.layout(std, uncertainty=True))
    out["expanded"] = dict(k=k, **ident.layout(k * std, uncertainty=True))
    if samples is not None and intervals:
        lo, hi = np.percentile(samples, [50 * (1 - coverage), 50 * (1 + coverage)], axis=0)
        out["coverage_interval"] = {"p": coverage, "low": ident.layout(lo), "high": ident.layout(hi)}
    out["budget"] = budget.name
    out["parameters"] = {"names": list(ident.names), "std": std.tolist()}
    out.update(extra or {})
    return out
