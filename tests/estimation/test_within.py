"""The large-problem algebra within the constraints equals the dense reference on small problems.

``calibration.Within`` has two paths: dense (explicit null-space basis, eigen-decomposition: the reference)
and large (Householder reflectors, Cholesky, Lanczos, conjugate-gradient LM steps), chosen by the number of
decision variables (``LARGE_PROBLEM``). Here both run on the same small problems -- random normal matrices
with gauge rows, the UR5 calibration, the SCARA error-map identification -- and must give the same rank,
the same unidentifiable names, condition number, covariance and solution. Units: mm, deg.
"""

from pathlib import Path

import numpy as np
import pytest

import olti_drake
from olti_drake.estimation import calibration
from olti_drake.estimation.calibration import Calibration
from olti_drake.estimation.calibration import SolverOptions, UnidentifiableError, Within


def _normal(seed, n=40, m=3, rows=150, duplicate=None):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(rows, n)) * rng.uniform(0.1, 10.0, n)
    if duplicate is not None:
        J[:, duplicate[1]] = 2.0 * J[:, duplicate[0]]
    A = rng.normal(size=(m, n))
    A[:, 6:] = 0.0  # gauge rows on a few parameters, as the models' are
    return J.T @ J, A


@pytest.mark.parametrize("m", [0, 1, 3])
def test_large_path_equals_dense_on_a_random_normal_matrix(m):
    H, A = _normal(1, m=m)
    dense, large = Within(H, A, large=False), Within(H, A, large=True)
    assert large.dim == dense.dim == H.shape[0] - m
    assert large.condition() == pytest.approx(dense.condition(), rel=1e-6)
    ref = dense.inverse()
    assert np.abs(large.inverse() - ref).max() <= 1e-10 * np.abs(ref).max()
    assert large.inverse_diagonal() == pytest.approx(np.diag(ref), rel=1e-9)
    g = np.random.default_rng(2).normal(size=H.shape[0])
    steps = [w.to_full(w.solve(w.to_null(g))) for w in (dense, large)]
    assert np.abs(steps[0] - steps[1]).max() <= 1e-10 * np.abs(steps[0]).max()
    assert not large.deficient() and large.weak_names([f"p{i}" for i in range(H.shape[0])]) == []


def test_clearly_regular_is_a_cheap_sufficient_test_of_full_rank():
    """dpocon's estimate says full rank (margin 100 x RANK_TOLERANCE) on a well-posed M; on a nearly deficient
    one (λ_min/λ_max ~ 1e-13: the Cholesky still succeeds) it decides nothing, and Lanczos finds the deficiency."""
    H, A = _normal(5, m=1)
    assert Within(H, A, large=True).clearly_regular()
    rng = np.random.default_rng(6)
    J = rng.normal(size=(150, 40))
    J[:, 11] = 2.0 * J[:, 10] + 1e-7 * rng.normal(size=150)  # (relative eigenvalue ~1e-15: below the tolerance)
    near = Within(J.T @ J, np.zeros((0, 40)), large=True)
    assert near.factorized and not near.clearly_regular() and near.deficient()
    assert not Within(H, A, large=False).clearly_regular()  # (dense path: no factor, never decided here)


def test_dependent_constraint_rows_count_once():
    """A constraint given twice (or a combination of others) removes one dimension, in both paths."""
    H, A = _normal(3, m=2)
    A = np.vstack([A, A[0] + A[1]])
    dense, large = Within(H, A, large=False), Within(H, A, large=True)
    assert dense.dim == large.dim == H.shape[0] - 2
    assert large.condition() == pytest.approx(dense.condition(), rel=1e-6)


def test_rank_deficiency_names_the_same_parameters_in_both_paths():
    H, A = _normal(4, duplicate=(10, 11))
    names = [f"p{i}" for i in range(H.shape[0])]
    dense, large = Within(H, A, large=False), Within(H, A, large=True)
    assert dense.deficient() and large.deficient()
    assert large.weak_names(names) == dense.weak_names(names) == ["p10", "p11"]
    assert large.condition() == dense.condition() == float("inf")


@pytest.fixture(scope="module")
def ur5_problem():
    from olti_drake.model.chain import load_serial_chain
    from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge, synthetic_campaign,
                                         synthetic_truth)

    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    truth = synthetic_truth(chain, seed=5, tool_offset_mm=(40.0, -25.0, 60.0))
    ranges = np.tile([-90.0, 90.0], (chain.n_joints, 1))
    camp = synthetic_campaign(truth, 150, seed=6, ranges_deg=ranges, noise_mm=0.0005)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=30.0,
                                 tool_offset_mm=(40.0, -25.0, 60.0))
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    return meas, find_gauge(meas)


def _fit_both(monkeypatch, build):
    dense = build().fit()
    monkeypatch.setattr(calibration, "LARGE_PROBLEM", 0)
    steps = []
    cg_step = calibration.LeastSquaresProgram._cg_step
    monkeypatch.setattr(calibration.LeastSquaresProgram, "_cg_step",
                        lambda self, *a: steps.append(1) or cg_step(self, *a))
    large = build().fit()
    assert steps  # the large path ran: conjugate-gradient steps within the gauge
    return dense, large


def test_calibration_large_path_equals_dense(monkeypatch, ur5_problem):
    meas, gauge = ur5_problem
    dense, large = _fit_both(monkeypatch, lambda: Calibration(meas, SolverOptions(), gauge, "synthetic UR5"))
    # Gauge-held parameters (std 0) agree to rounding (1e-13 mm).
    assert np.all(np.abs(large.x - dense.x) <= 1e-4 * dense.std + 1e-10)
    assert large.std == pytest.approx(dense.std, rel=1e-6, abs=1e-12)
    assert np.abs(large.covariance - dense.covariance).max() <= 1e-6 * np.abs(dense.covariance).max()
    assert large.condition_number == pytest.approx(dense.condition_number, rel=1e-6)
    assert large.converged_by and dense.converged_by


def test_unidentifiable_names_agree_in_both_paths(monkeypatch, ur5_problem):
    """Without the gauge the rotation about J1 and the base placement are invisible: the same names, by
    both paths."""
    meas, _ = ur5_problem
    errors = []
    for limit in (calibration.LARGE_PROBLEM, 0):
        monkeypatch.setattr(calibration, "LARGE_PROBLEM", limit)
        with pytest.raises(UnidentifiableError) as e:
            Calibration(meas, SolverOptions(), None, "synthetic UR5").fit()
        errors.append(e.value)
    assert errors[0].names and errors[0].names == errors[1].names
    assert str(errors[0]) == str(errors[1])


def test_scara_identification_large_path_equals_dense(monkeypatch):
    from olti_drake.estimation.identification import IdentificationOptions, Identifier
    from olti_drake.io.csvio import load_campaign

    data = load_campaign(Path(__file__).resolve().parents[2] / "data" / "paper000" / "campaign.csv")
    dense, large = _fit_both(monkeypatch, lambda: Identifier(data, IdentificationOptions(model="errormap")))
    # Both stop when the cost no longer decreases by 1e-12 of itself: the same minimum, to far below u.
    assert np.max(np.abs(large.x - dense.x) / dense.std) < 1e-4
    assert large.std == pytest.approx(dense.std, rel=1e-6)
    assert large.condition_number == pytest.approx(dense.condition_number, rel=1e-6)


def test_monte_carlo_of_a_calibration_solves_each_trial(ur5_problem):
    """Calibration programs (no batched residuals) go trial by trial: each trial is its own least-squares
    solution (a full fit of the same readings agrees), seeded, and the spread follows the linear method."""
    from olti_drake.estimation import uncertainty
    from olti_drake.io.budget import default_budget
    from olti_drake.model.budget import ReadingErrors

    meas, gauge = ur5_problem
    cal = Calibration(meas, SolverOptions(), gauge, "synthetic UR5")
    x = cal.fit().x
    errors = ReadingErrors(default_budget("scara"))
    mc = uncertainty.monte_carlo(cal, x, errors, trials=300, seed=2, workers=1)
    again = uncertainty.monte_carlo(cal, x, errors, trials=300, seed=2, workers=1)
    assert np.array_equal(mc.samples, again.samples)
    u = np.sqrt(np.diag(uncertainty.linear_covariance(cal, x, errors)))
    seen = u > 1e-9 * u.max()  # the gauge's own combinations have none
    assert mc.samples.std(axis=0, ddof=1)[seen] == pytest.approx(u[seen], rel=0.25)
    # One trial re-solved from scratch: the readings the trial saw, identified by LM.
    r0 = cal.residuals(x)[0]
    E = errors.draw(np.random.default_rng(9), cal.beam_lengths(x), 1)
    B, _ = uncertainty._solution_map(cal, x)
    n = len(x)
    trial = uncertainty._solve_trials_one_by_one(cal, x, B, r0 + E, np.zeros(n), np.zeros((n, n)))[0]
    saved = meas.displacement
    try:
        meas.displacement = meas.predict(x) + E[0]
        refit = Calibration(meas, SolverOptions(), gauge, "trial").fit().x
    finally:
        meas.displacement = saved
    # Both stop where the predicted decrease is below 1e-12 of the cost: within 1e-5 u of each other.
    assert np.all(np.abs(trial - refit) <= 1e-5 * u + 1e-10)


@pytest.mark.parametrize("interleaved", [False, True])
def test_normal_matrix_of_a_wide_jacobian_equals_the_dense_product(interleaved):
    """Wide J (above SMALL_PROBLEM columns): busy columns by BLAS, the rest sparse (one block, or scattered
    among the busy ones) -- the same JᵀWJ; the LM operator's diagonal too."""
    import scipy.sparse as sp

    rng = np.random.default_rng(7)
    rows, n, busy = 3000, calibration.SMALL_PROBLEM + 100, 25
    dense = np.zeros((rows, n))
    dense[:, :busy] = rng.normal(size=(rows, busy))
    for k in range(rows):
        dense[k, busy + rng.choice(n - busy, 4, replace=False)] = rng.normal(size=4)
    dense[:, n - 1] = 0.0  # a column no row touches
    if interleaved:
        dense = dense[:, np.random.default_rng(8).permutation(n)]
    w = rng.uniform(0.2, 1.0, rows)
    expect = dense.T @ (w[:, None] * dense)
    J = sp.csr_matrix(dense)
    assert np.abs(calibration._normal_matrix(J, w) - expect).max() <= 1e-12 * np.abs(expect).max()
    assert calibration._NormalOperator(J, w).diagonal() == pytest.approx(np.diag(expect), rel=1e-12)


# -- above REUSE_ABOVE: the check's rank work beside LM, the covariance from the start's factorization ----------
class _Linear:
    """r = J x − y (mm): a linear measurement, enough for the program's algebra."""

    def __init__(self, J, y):
        import scipy.sparse as sp

        self.J, self.y = sp.csr_matrix(J), y
        self.names = [f"p{i}" for i in range(J.shape[1])]

    def start_vector(self):
        return np.zeros(self.J.shape[1])

    def residuals(self, x):
        return self.J @ x - self.y, self.J

    def beam_lengths(self, x, residuals=None):
        return np.ones(len(self.y))

    def layout(self, v):
        return {}


@pytest.fixture
def reuse_everywhere(monkeypatch):
    """The large path and the reuse of the start's factorization on small problems; records the deferred checks."""
    monkeypatch.setattr(calibration, "LARGE_PROBLEM", 0)
    monkeypatch.setattr(calibration, "REUSE_ABOVE", 0)
    started = []
    start = calibration.Within.start_background
    monkeypatch.setattr(calibration.Within, "start_background", lambda self: started.append(1) or start(self))
    return started


def test_a_deficiency_the_factorization_misses_is_named_after_the_deferred_check(reuse_everywhere):
    """A nearly repeated column (rank deficient at 1e-12 but Cholesky succeeds): the thread's Lanczos finds it,
    the same names as the dense path; with regularize the weak prior is added and the fit goes on."""
    rng = np.random.default_rng(0)
    J = rng.normal(size=(400, 60))
    J[:, 11] = 2.0 * J[:, 10] + 1e-7 * rng.normal(size=400)
    y = J @ rng.normal(size=60) + 1e-3 * rng.normal(size=400)
    with pytest.raises(UnidentifiableError) as e:
        Calibration(_Linear(J, y)).fit()
    assert reuse_everywhere and e.value.names == ["p10", "p11"]
    fit = Calibration(_Linear(J, y), SolverOptions(regularize=True)).fit()
    assert fit.converged_by and any("regularized" in n and "p10, p11" in n for n in fit.notes)


def test_the_start_factorization_serves_the_covariance_within_its_stated_bound(monkeypatch, reuse_everywhere,
                                                                              ur5_problem):
    """Reused (tolerance 1): the note states ε, the estimate of ‖F‖ (a Ritz value: never above the exact
    norm, computed here densely, and close to it), and every u is within the factor it implies of the
    dense path's at the solution. Tolerance 0: refactorized at the solution, equal to the dense path."""
    import re

    meas, gauge = ur5_problem
    dense = Calibration(meas, SolverOptions(), gauge, "UR5").fit()
    monkeypatch.setattr(calibration, "REUSE_TOLERANCE", 1.0)
    cal = Calibration(meas, SolverOptions(), gauge, "UR5")
    reused = cal.fit()
    assert reuse_everywhere
    eps = float(re.search(r"differ by ([0-9.e+-]+) in its metric", " ".join(reused.notes)).group(1))
    W0 = Within(cal._normal(cal._pad(cal._checked[2]), np.ones(len(dense.residuals))), cal._equality_rows()[0],
                large=True)
    U = np.triu(W0._U)
    F = np.linalg.solve(U.T, np.linalg.solve(U.T, (W0.to_null(W0.to_null(
        cal._normal(cal.residuals(reused.x)[1], np.ones(len(dense.residuals))) / np.outer(W0.s, W0.s)).T)
        - W0.M)).T)
    exact = np.abs(np.linalg.eigvalsh(0.5 * (F + F.T))).max()
    assert 0.7 * exact <= eps <= 1.1 * exact  # (stated rounded up to 2 digits)
    seen = dense.std > 1e-9 * dense.std.max()
    ratio = reused.std[seen] / dense.std[seen]
    assert np.all((ratio >= 1 / np.sqrt(1 + exact) - 1e-9) & (ratio <= 1 / np.sqrt(1 - exact) + 1e-9))
    assert reused.condition_number == pytest.approx(dense.condition_number, rel=exact)
    monkeypatch.setattr(calibration, "REUSE_TOLERANCE", 0.0)
    refactored = Calibration(meas, SolverOptions(), gauge, "UR5").fit()
    assert not any("identifiability check's factorization" in n for n in refactored.notes)
    assert refactored.std == pytest.approx(dense.std, rel=1e-6, abs=1e-12)


def test_single_precision_variances_agree_with_double_or_are_redone(monkeypatch, ur5_problem):
    """Above THOUSANDS unknowns the variances come from a single-precision U⁻¹ checked on sampled rows: they agree
    with the double-precision ones to INVERSE_RTOL; a tolerance no single-precision inverse meets sends them
    back to double precision (equal to the dense path)."""
    meas, gauge = ur5_problem
    cal = Calibration(meas, SolverOptions(), gauge, "UR5")
    r, J = cal.residuals(cal.x0)
    H = cal._normal(cal._pad(J), np.ones(len(r)))
    A = cal._equality_rows()[0]
    exact = Within(H.copy(), A, large=True).inverse_diagonal()
    monkeypatch.setattr(calibration, "THOUSANDS", 0)
    single = Within(H.copy(), A, large=True)
    assert single._row_norms_agree(single._inverse_row_norms(np.float32))
    assert single.inverse_diagonal() == pytest.approx(exact, rel=calibration.INVERSE_RTOL, abs=1e-300)
    monkeypatch.setattr(calibration, "INVERSE_RTOL", 1e-15)
    redone = Within(H.copy(), A, large=True)
    assert not redone._row_norms_agree(redone._inverse_row_norms(np.float32))
    assert redone.inverse_diagonal() == pytest.approx(exact, rel=1e-9, abs=1e-300)


def test_the_nlp_solver_reaches_the_lm_solution_of_a_six_axis_error_map(ur5_problem):
    """solver='nlp' (SNOPT through Drake's Solve of the whole program) on the UR5 error-map problem: it ran into
    SNOPT's default iteration limit before; with the program's limit it converges to LM's solution."""
    meas, gauge = ur5_problem
    lm = Calibration(meas, SolverOptions(), gauge, "UR5").fit()
    nlp = Calibration(meas, SolverOptions(solver="nlp"), gauge, "UR5").fit()
    assert nlp.converged_by and np.all(np.abs(nlp.x - lm.x) <= 1e-3 * lm.std + 1e-9)


def test_lm_stops_where_no_parameter_would_move_by_a_percent_of_its_uncertainty(monkeypatch, ur5_problem):
    """Above LARGE_PROBLEM variables LM does not evaluate a step that would change no parameter by more than
    STEP_FRACTION of its standard uncertainty: it says so, and the solution is within that of LM's run to
    1e-12 of the cost (STEP_FRACTION 0), with fewer evaluations."""
    meas, gauge = ur5_problem
    monkeypatch.setattr(calibration, "LARGE_PROBLEM", 0)
    counted = []
    residuals = Calibration.residuals
    monkeypatch.setattr(Calibration, "residuals", lambda self, x: counted.append(1) or residuals(self, x))
    early = Calibration(meas, SolverOptions(), gauge, "UR5").fit()
    n_early, fraction = len(counted), calibration.STEP_FRACTION
    monkeypatch.setattr(calibration, "STEP_FRACTION", 0.0)
    counted.clear()
    tight = Calibration(meas, SolverOptions(), gauge, "UR5").fit()
    assert "1% of its standard uncertainty" in early.converged_by
    assert "1e-12" in tight.converged_by and n_early < len(counted)
    assert np.all(np.abs(early.x - tight.x) <= fraction * tight.std + 1e-12)
    assert early.std == pytest.approx(tight.std, rel=1e-3)


def test_the_factorization_takes_every_blas_thread_only_when_large_and_alone(monkeypatch):
    """Above THOUSANDS unknowns and with no helper thread at work: the process's starting BLAS threads;
    otherwise the caller's setting (one thread inside fit)."""
    import threading

    from olti_drake import threads

    controls = threads._openblas_controls()
    if not controls:
        pytest.skip("no OpenBLAS found in this process")
    counts = lambda: [get() for get, _ in controls]  # noqa: E731
    with threads.single_thread_blas():
        with calibration._factor_threads(calibration.THOUSANDS):
            assert counts() == [1] * len(controls)
        with calibration._factor_threads(calibration.THOUSANDS + 1):
            assert counts() == threads._STARTED
        release = threading.Event()
        helper = threading.Thread(target=release.wait, name=calibration.HELPER_THREAD)
        helper.start()
        try:
            with calibration._factor_threads(calibration.THOUSANDS + 1):
                assert counts() == [1] * len(controls)
        finally:
            release.set()
            helper.join()
        assert counts() == [1] * len(controls)
