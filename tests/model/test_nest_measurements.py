"""The five-axis campaign's measurements over any position model of dim 3 (issue 25 item 3; formats.md "Five-axis
machine tools"): R-test / 3D-probe displacements from nests with their own zeros, tracker points in an unknown
tracker frame, and one campaign mixing them with distances (:mod:`olti_drake.model.displacements`), on the
volumetric machine (:class:`VolumetricPositionModel`, truth outside the spline family:
:func:`volumetric3d.synthetic_truth`) and the free points of 001, identified by the one engine
(:class:`~olti_drake.estimation.calibration.Calibration`). Units: mm, µrad."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import Calibration, SolverOptions
from olti_drake.model.displacements import CombinedMeasurement, NestDisplacementMeasurement, PointMeasurement
from olti_drake.model.frames import left_jacobian, rigid_fit, rotation_matrix, rotation_vector
from olti_drake.model.free_points import FreePoints
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.model.volumetric3d import (MachineConfig, VolumetricModel, VolumetricPositionModel, synthetic_truth,
                                           tool_positions)

TOOLS_MM = ((0.0, 0.0, 100.0), (150.0, 0.0, 100.0), (0.0, 150.0, 140.0))
NESTS_MM = np.array([[100.0, 80.0, 50.0], [300.0, 80.0, 50.0], [100.0, 220.0, 50.0], [300.0, 220.0, 50.0]])
STATIONS_MM = np.array([[-300.0, -200.0, 50.0], [700.0, -250.0, 80.0], [650.0, 600.0, 20.0], [-250.0, 550.0, 400.0]])
SIGMA_NEST_MM = 1e-3  # R-test: 1 µm per coordinate
SIGMA_DISTANCE_MM = 0.5e-3  # interferometer: 0.5 µm


@pytest.fixture(scope="module")
def machine():
    """A 3-axis machine on a 50 mm knot grid (147 unknowns), 240 random commands with three tools, and a seeded
    truth outside the spline family (sines of periods >= 350 mm: spline bound <= 0.04 µm, 0.1 µrad)."""
    cfg = MachineConfig(tool_offsets_mm=TOOLS_MM, knot_spacing_mm=50.0)
    truth = synthetic_truth(cfg, seed=7, min_period_intervals=7.0)
    rng = np.random.default_rng(5)
    cmd = rng.uniform([0, 0, 0], [400, 300, 250], (240, 3))
    tool = rng.integers(0, 3, len(cmd))
    model = VolumetricPositionModel(VolumetricModel(cfg), cmd, tool)
    return model, tool_positions(cfg, truth, cmd, tool)


def _r_test(model, p_true, seed, sigma=SIGMA_NEST_MM):
    """Every point read from two random nests (so the nests' zeros are tied together), noise σ per coordinate."""
    rng = np.random.default_rng(seed)
    n = model.n_points
    points = np.concatenate([np.arange(n), np.arange(n)])
    nest = rng.integers(0, len(NESTS_MM), len(points))
    d = p_true[points] - NESTS_MM[nest] + sigma * rng.standard_normal((len(points), 3))
    return points, nest, d


def _distances(model, p_true, seed, sigma=SIGMA_DISTANCE_MM, every=2):
    """001 Eq. (3) from four stations (dead path 0 at the truth), every ``every``-th point, noise σ; the
    stations started 0.2 mm off the truth."""
    rng = np.random.default_rng(seed)
    pts = np.arange(0, model.n_points, every)
    points, station = np.repeat(pts, len(STATIONS_MM)), np.tile(np.arange(len(STATIONS_MM)), len(pts))
    d = np.linalg.norm(p_true[points] - STATIONS_MM[station], axis=1) + sigma * rng.standard_normal(len(points))
    start = STATIONS_MM + rng.uniform(-0.2, 0.2, STATIONS_MM.shape)
    return StationDistanceMeasurement(model, points, station, d, start, np.zeros(len(STATIONS_MM)))


def _covariance(fit):
    c = fit.covariance
    return np.asarray(c() if callable(c) else c)


def _point_check(model, fit, p_true):
    """(|error| / u of every predicted tool point coordinate, u mm): the fit's covariance through the model's
    Jacobian (k = 1)."""
    n = model.n_params
    p, J = model.jacobian(fit.x[:n])
    A = J.tocsr().toarray()
    u = np.sqrt(np.einsum("ij,jk,ik->i", A, _covariance(fit)[:n, :n], A))
    return np.abs((p - p_true).ravel()) / u, u


def _numeric_jacobian(meas, x, columns):
    """Central differences of the residuals in ``columns``, step 1e-6 of each parameter's size (at least 1e-6 of
    its unit); other columns 0."""
    J = np.zeros((len(meas.residuals(x)[0]), len(x)))
    for j in columns:
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros(len(x))
        e[j] = h
        J[:, j] = (meas.residuals(x + e)[0] - meas.residuals(x - e)[0]) / (2 * h)
    return J


def _free_points():
    rng = np.random.default_rng(1)
    return FreePoints(rng.uniform(0, 300, (9, 3)))


def _small_volumetric():
    cfg = MachineConfig(tool_offsets_mm=TOOLS_MM[:2], knot_spacing_mm=200.0)
    rng = np.random.default_rng(2)
    return VolumetricPositionModel(VolumetricModel(cfg, identify_tool_offsets=True),
                                   rng.uniform([0, 0, 0], [400, 300, 250], (12, 3)), np.repeat([0, 1], 6))


def _kinds(model, rng):
    """One measurement of each kind on ``model`` (readings random around its start points), and them combined."""
    n = model.n_points
    p0 = model.positions()
    points = rng.integers(0, n, 20)
    nest = NestDisplacementMeasurement(model, points, rng.integers(0, 2, 20), p0[points] - [50, 60, 10]
                                       + rng.normal(0, 0.01, (20, 3)), sigma_mm=1e-3)
    frame = np.array([800.0, -300.0, 200.0, 0.4e6, -0.9e6, 2.2e6])  # t mm, w µrad (|w| = 2.4 rad)
    q = p0[points] @ rotation_matrix(frame[3:] * 1e-6).T + frame[:3]
    point = PointMeasurement(model, points, rng.integers(0, 2, 20), q + rng.normal(0, 0.01, (20, 3)), sigma_mm=2e-3)
    dist = StationDistanceMeasurement(model, points, rng.integers(0, 2, 20), rng.uniform(100, 200, 20),
                                      [[-200.0, 0, 0], [500.0, 400, 300]], [0.0, 1.0])
    return nest, point, CombinedMeasurement(model, [dist, nest, point], [0.5e-3, 1e-3, 2e-3])


@pytest.mark.parametrize("make", (_free_points, _small_volumetric), ids=("free_points", "volumetric"))
def test_jacobians_equal_central_differences_and_batched_rows(make):
    """Every measurement's analytic sparse Jacobian equals central differences at a perturbed x (large tracker
    rotations included: the left Jacobian of SO(3)); the batched rows of the Monte Carlo equal residuals()."""
    model = make()
    rng = np.random.default_rng(11)
    for meas in _kinds(model, rng):
        x = meas.start_vector() + 1e-3 * rng.standard_normal(len(meas.names))
        r, J = meas.residuals(x)
        J = J.toarray()
        if meas.kind == "combined":  # (all three kinds' rows, each scaled: one pass of differences)
            columns = np.r_[0:meas.n_model:3, meas.n_model:len(x)]  # (every 3rd of the model's: time)
            num = _numeric_jacobian(meas, x, columns)
            assert np.abs(J[:, columns] - num[:, columns]).max() <= 1e-6 * max(1.0, np.abs(num).max())
        X = x + 1e-4 * rng.standard_normal((3, len(x)))
        rr, cols, vals = meas.residual_rows(X)
        for t in range(3):
            r_t, J_t = meas.residuals(X[t])
            np.testing.assert_allclose(rr[t], r_t, rtol=0, atol=1e-12)
            dense = np.zeros_like(J)
            np.add.at(dense, (np.repeat(np.arange(len(cols)), cols.shape[1]), cols.ravel()), vals[t].ravel())
            np.testing.assert_allclose(dense, J_t.toarray(), rtol=0, atol=1e-12)
        assert len(meas.beam_lengths(x)) == len(r) and len(meas.names) == len(set(meas.names))
        R = meas.roughness()  # (the model's smoothness rows, padded over the measurement's own parameters)
        assert R is None or R.shape[1] == len(meas.names)


def test_rotations():
    """exp / log / left Jacobian of SO(3) against scipy's rotations and central differences."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    for w in (np.array([1.2, -0.7, 2.1]), rng.normal(0, 0.5, 3), np.array([1e-7, -2e-7, 3e-8]), np.array([0.0, 0.0, np.pi - 1e-3])):
        R = rotation_matrix(w)
        np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
        np.testing.assert_allclose(rotation_vector(R), w, atol=1e-9)
        p = np.array([300.0, -100.0, 50.0])
        num = np.column_stack([(rotation_matrix(w + e) @ p - rotation_matrix(w - e) @ p) / 2e-7
                               for e in 1e-7 * np.eye(3)])
        q = R @ p
        skew = np.array([[0, -q[2], q[1]], [q[2], 0, -q[0]], [-q[1], q[0], 0]])
        np.testing.assert_allclose(-skew @ left_jacobian(w), num, atol=1e-6)


def test_r_test_campaign_recovers_the_machine_within_its_uncertainty(machine):
    """Simulated R-test readings (four nests, every point read from two, 1 µm noise) of a truth outside the spline
    family identify through Calibration: every predicted tool point within 3 u (k = 1) of the truth for >= 95 %
    of coordinates, the nest zeros within 3 u, and u not absurd (median below the readings' σ, errors/u RMS
    0.3-2)."""
    model, p_true = machine
    points, nest, d = _r_test(model, p_true, seed=8)
    meas = NestDisplacementMeasurement(model, points, nest, d, sigma_mm=SIGMA_NEST_MM)
    fit = Calibration(meas, SolverOptions(), None, "R-test").fit()
    z, u = _point_check(model, fit, p_true)
    assert np.mean(z <= 3.0) >= 0.95 and 0.3 <= np.sqrt(np.mean(z ** 2)) <= 2.0, (np.mean(z <= 3), z.max())
    assert np.median(u) < SIGMA_NEST_MM and u.max() < 3 * SIGMA_NEST_MM
    nests = meas.split(fit.x)[1]
    u_nests = meas.split(fit.std)[1]
    assert np.all(np.abs(nests - NESTS_MM) <= 3 * u_nests) and u_nests.max() < SIGMA_NEST_MM
    assert "nests_mm" in meas.layout(fit.x) and meas.implausible(fit.x) == []
    spread, motion = meas.reading_spans()  # (mm readings spread as their points: no unit slip)
    assert 0.9 * motion < spread < 1.1 * motion
    assert "translation" in meas.GAUGE


def test_a_nest_read_alone_is_a_translation_the_engine_names():
    """A nest zero absorbs a translation of the points it sees: points read only by a nest whose readings are
    their sole ones leave that nest and their common translation inseparable only when nothing else ties
    them -- on free points (every point its own unknowns) the engine names the rank deficiency."""
    from olti_drake.estimation.calibration import UnidentifiableError

    fp = _free_points()
    p = fp.positions()
    meas = NestDisplacementMeasurement(fp, np.arange(9), np.zeros(9, int), p - [10.0, 20.0, 5.0])
    with pytest.raises(UnidentifiableError, match="rank deficient by 3"):
        Calibration(meas, SolverOptions(), None, "one nest").fit()


def test_mixed_campaign_distances_r_test_and_tracker(machine):
    """One campaign mixing distances (0.5 µm), R-test readings (1 µm) and tracker points (2 µm, a frame turned
    by 0.6 rad), each weighed by its σ: solves, the residual RMS is σ_ref (the weights right), the tool points
    within 3 u, and better determined than by the R-test alone."""
    model, p_true = machine
    points, nest, d = _r_test(model, p_true, seed=9)
    nests = NestDisplacementMeasurement(model, points, nest, d, sigma_mm=SIGMA_NEST_MM)
    dist = _distances(model, p_true, seed=10)
    rng = np.random.default_rng(16)
    frame = np.array([2000.0, 500.0, -300.0, 0.1e6, -0.2e6, 0.55e6])
    seen = np.arange(1, model.n_points, 3)
    q = p_true[seen] @ rotation_matrix(frame[3:] * 1e-6).T + frame[:3] + 2e-3 * rng.standard_normal((len(seen), 3))
    tracker = PointMeasurement(model, seen, np.zeros(len(seen), int), q, sigma_mm=2e-3)
    mixed = CombinedMeasurement(model, [dist, nests, tracker], [SIGMA_DISTANCE_MM, None, None])  # (None: its own)
    assert mixed.scales.tolist() == [1.0, 0.5, 0.25]
    fit = Calibration(mixed, SolverOptions(), None, "mixed").fit()
    z, u = _point_check(model, fit, p_true)
    assert np.mean(z <= 3.0) >= 0.95 and np.sqrt(np.mean(z ** 2)) <= 2.0
    rms = np.sqrt(np.mean(fit.residuals ** 2))
    assert 0.8 * SIGMA_DISTANCE_MM < rms < 1.2 * SIGMA_DISTANCE_MM
    got, u_frame = (tracker.split(mixed.part(v, 2))[1][0] for v in (fit.x, fit.std))
    assert np.all(np.abs(got - frame) <= 3 * u_frame) and u_frame[:3].max() < 2e-3 and u_frame[3:].max() < 2.0
    alone = Calibration(nests, SolverOptions(), None, "R-test").fit()
    assert np.median(u) < np.median(_point_check(model, alone, p_true)[1])
    r_dist, r_nest, r_tracker = mixed.unscaled(fit.residuals)
    assert len(r_dist) == len(dist.displacement) and len(r_nest) == 3 * len(points) == nests.n_rows
    assert 0.7 * 2e-3 < np.sqrt(np.mean(r_tracker ** 2)) < 1.2 * 2e-3
    layout = mixed.layout(fit.x)
    assert {"model", "stations_mm", "dead_paths_mm", "nests_mm", "tracker_frames"} <= set(layout)


def test_monte_carlo_of_a_mixed_campaign_on_free_points():
    """The batched rows of a mixed campaign (distances 0.5 µm, R-test 1 µm) on the free points of 001 serve the
    engine's Monte Carlo (JCGM 101): with a budget of the reference σ (the rows scaled to it) its u equal the
    linear propagation's within the scatter of 400 trials (±15 %). Gauge: the nests see the workpiece axes
    (no rotation left), nests and stations a common translation -- fixed by the mean of the points."""
    from olti_drake.estimation.uncertainty import linear_covariance, monte_carlo
    from olti_drake.model.budget import Budget, Contributor, ReadingErrors
    from olti_drake.model.gauges import NamedGauge

    rng = np.random.default_rng(21)
    fp = FreePoints(rng.uniform([0, 0, 0], [400, 300, 250], (30, 3)))
    p_true = fp.nominal_mm + rng.normal(0, 0.01, (30, 3))
    points, nest, d = _r_test(fp, p_true, seed=22)
    pts, st = np.repeat(np.arange(30), 4), np.tile(np.arange(4), 30)
    dd = np.linalg.norm(p_true[pts] - STATIONS_MM[st], axis=1) + SIGMA_DISTANCE_MM * rng.standard_normal(len(pts))
    both = CombinedMeasurement(fp, [StationDistanceMeasurement(fp, pts, st, dd, STATIONS_MM + 0.1, np.zeros(4)),
                                    NestDisplacementMeasurement(fp, points, nest, d, sigma_mm=SIGMA_NEST_MM)],
                               [SIGMA_DISTANCE_MM, SIGMA_NEST_MM])
    A = np.zeros((3, len(both.names)))
    for k in range(3):
        A[k, k:90:3] = 1.0
    gauge = NamedGauge("translation", A, A[:, :90] @ fp.nominal_mm.ravel(), "the points' mean translation fixed")
    budget = Budget("interferometer", "test", [Contributor("u", "reading", 0.5, "um", 1.0)])
    cal = Calibration(both, SolverOptions(budget=budget), gauge, "free points")
    fit = cal.fit()
    linear = np.sqrt(np.diag(linear_covariance(cal, fit.x, ReadingErrors(budget))))
    mc = monte_carlo(cal, fit.x, ReadingErrors(budget), trials=400, workers=1, seed=3)
    ratio = mc.samples.std(axis=0, ddof=1) / linear
    assert 0.85 <= ratio.min() and ratio.max() <= 1.15 and abs(np.median(ratio) - 1) < 0.05


def test_tracker_frame_recovered_noise_free(machine):
    """Noise-free tracker points (two set-ups, rotations of 0.5 and 2.4 rad) of a machine inside the family: the
    frames recovered to < 1 µm and < 1 µrad from the Kabsch start, the machine exactly."""
    model, _ = machine
    rng = np.random.default_rng(12)
    x_true = np.where([n.startswith("E_") and n[2] in "ABC" for n in model.names],
                      rng.normal(0, 5.0, model.n_params), rng.normal(0, 0.003, model.n_params))
    p = model.positions(x_true)
    frames = np.array([[1500.0, -800.0, 300.0, 0.2e6, -0.3e6, 0.35e6], [-900.0, 1200.0, -50.0, 0.9e6, 1.4e6, -1.7e6]])
    group = np.arange(model.n_points) % 2
    q = np.einsum("kac,kc->ka", rotation_matrix(frames[group, 3:] * 1e-6), p) + frames[group, :3]
    meas = PointMeasurement(model, np.arange(model.n_points), group, q)
    fit = Calibration(meas, SolverOptions(), None, "tracker").fit(uncertainty=False)
    got = meas.split(fit.x)[1]
    assert np.abs(got[:, :3] - frames[:, :3]).max() < 1e-3 and np.abs(got[:, 3:] - frames[:, 3:]).max() < 1.0
    assert np.abs(model.positions(fit.x[:model.n_params]) - p).max() < 1e-6
    R0, t0 = rigid_fit(p[group == 0], q[group == 0])
    np.testing.assert_allclose(R0, rotation_matrix(frames[0, 3:] * 1e-6), atol=1e-12)
    np.testing.assert_allclose(t0, frames[0, :3], atol=1e-9)


def test_results_do_not_depend_on_row_order(machine):
    """Shuffled readings give the same solution to 1e-9 of every parameter's u (and 1e-8 mm / µrad)."""
    model, p_true = machine
    points, nest, d = _r_test(model, p_true, seed=13)
    dist = _distances(model, p_true, seed=14, every=4)
    order = np.random.default_rng(15).permutation(len(points))
    fits = []
    for o in (np.arange(len(points)), order):
        nests = NestDisplacementMeasurement(model, points[o], nest[o], d[o], sigma_mm=SIGMA_NEST_MM)
        both = CombinedMeasurement(model, [nests, dist], [SIGMA_NEST_MM, SIGMA_DISTANCE_MM])
        fits.append(Calibration(both, SolverOptions(), None, "mixed").fit())
    change = np.abs(fits[0].x - fits[1].x)
    # (to LM's stop, a relative cost decrease of 1e-12: measured 1.1e-9 µrad on a coefficient of u 4.8 µrad)
    assert np.max(change / fits[0].std) <= 1e-9 and change.max() <= 1e-8


@pytest.mark.parametrize("build, message", [
    (lambda m: NestDisplacementMeasurement(m, [0, 1], [0, 0], [[0, 0, 0]]), "displacement_mm"),
    (lambda m: NestDisplacementMeasurement(m, [0, 99], [0, 0], np.zeros((2, 3))), "points: row 1"),
    (lambda m: NestDisplacementMeasurement(m, [0, 1], [0, -1], np.zeros((2, 3))), "nest: row 1"),
    (lambda m: NestDisplacementMeasurement(m, [0, 1], [0, 0], [[0, 0, 0], [0, np.nan, 0]]), "row 1 is not finite"),
    (lambda m: NestDisplacementMeasurement(m, [0, 1], [0, 0], np.zeros((2, 3)), sigma_mm=-1), "sigma_mm"),
    (lambda m: PointMeasurement(m, [0, 1, 2], [0, 0, 0], m.positions()[[0, 0, 0]]), "tracker set-up 0"),
    (lambda m: PointMeasurement(m, [0, 1], ["a", 0], np.zeros((2, 3))), "frame_group: row 0"),
    (lambda m: CombinedMeasurement(m, [NestDisplacementMeasurement(m, [0], [0], np.zeros((1, 3)))] * 2),
     "repeats measurement 0"),
    (lambda m: CombinedMeasurement(m, [NestDisplacementMeasurement(m, [0], [0], np.zeros((1, 3)), sigma_mm=1e-3),
                                       PointMeasurement(m, [0, 1, 2], [0, 0, 0], m.positions()[:3])]),
     "measurement 1 \\(point\\) has no reading uncertainty"),
    (lambda m: CombinedMeasurement(m, [NestDisplacementMeasurement(_free_points(), [0], [0], np.zeros((1, 3)))]),
     "another position model"),
])
def test_bad_input_is_one_line_naming_it(build, message):
    with pytest.raises(InputError, match=message) as e:
        build(_free_points_fixed())
    assert "\n" not in str(e.value)


_FP = []


def _free_points_fixed():
    if not _FP:
        _FP.append(_free_points())
    return _FP[0]
