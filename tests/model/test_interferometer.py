"""The simulated interferometer: cosine error, beam loss, lambda/64 counter, budget noise."""

import numpy as np
import pytest

from olti_drake.model.budget import Budget, Contributor, paper000_budget
from olti_drake.model.instrument import (InterferometerOptions, beam_geometry, displacement_model,
                                       quantize, simulate_readings)

QUIET = InterferometerOptions(noise=False, quantization=False)


def _one(origin, angle, P, d0=0.0, options=QUIET, budget=None, seed=0):
    r, v, miss = simulate_readings(np.atleast_2d(origin), np.atleast_1d(angle), np.atleast_2d(P), [d0],
                                   options, budget or paper000_budget(), np.random.default_rng(seed))
    return r[0], bool(v[0]), miss[0]


def test_noise_free_reading_on_centre_is_distance_minus_dead_path():
    P = np.array([700.0, -50.0])
    o = np.array([123.0, 45.0])
    aim = np.degrees(np.arctan2(*(P - o)[::-1]))
    r, valid, miss = _one(o, aim, P, d0=100.0)
    assert valid and miss == pytest.approx(0, abs=1e-9)
    assert r == pytest.approx(np.hypot(*(P - o)) - 100.0, abs=1e-9)


def test_cosine_error_and_beam_loss():
    P = np.array([1000.0, 0.0])
    # Beam 0.8 mm off the centre at 1000 mm: reads sqrt(D^2 - m^2) = D - m^2/(2D) (000 Sec. 5).
    angle = np.degrees(np.arcsin(0.8 / 1000.0))
    r, valid, miss = _one([0, 0], angle, P)
    assert valid and miss == pytest.approx(0.8, rel=1e-9)
    assert r == pytest.approx(np.sqrt(1000.0**2 - 0.8**2), abs=1e-9)
    assert 1000.0 - r == pytest.approx(0.32e-3, rel=1e-3)
    # Switched off, the reading is the full distance.
    r_off, _, _ = _one([0, 0], angle, P, options=InterferometerOptions(noise=False, quantization=False,
                                                                      cosine_error=False))
    assert r_off == pytest.approx(1000.0, abs=1e-9)
    # 1.2 mm off: beyond the cat's eye acceptance of 1 mm -> invalid; with beam_loss off, kept.
    angle = np.degrees(np.arcsin(1.2 / 1000.0))
    assert not _one([0, 0], angle, P)[1]
    assert _one([0, 0], angle, P, options=InterferometerOptions(noise=False, beam_loss=False))[1]


def test_acceptance_is_a_setting():
    angle = np.degrees(np.arcsin(1.2 / 1000.0))
    opts = InterferometerOptions(noise=False, quantization=False, acceptance_mm=1.5)
    assert _one([0, 0], angle, [1000.0, 0.0], options=opts)[1]


def test_quantization_is_lambda_over_64():
    opts = InterferometerOptions(noise=False)
    step = 632.8e-6 / 64
    assert opts.resolution_mm == pytest.approx(step)
    r, _, _ = _one([0, 0], 0.0, [123.456789, 0.0], options=opts)
    assert r / step == pytest.approx(round(r / step), abs=1e-6)
    assert abs(r - 123.456789) <= step / 2 + 1e-12
    assert quantize([0.4 * step, 0.6 * step], step) == pytest.approx([0.0, step])


def test_noise_matches_budget_rss():
    budget = paper000_budget()
    n = 20000
    origin = np.zeros((n, 2))
    P = np.tile([800.0, 0.0], (n, 1))
    opts = InterferometerOptions(quantization=False, beam_loss=False)
    r, _, _ = simulate_readings(origin, np.zeros(n), P, np.zeros(n), opts, budget, np.random.default_rng(1))
    # Along the beam: pose terms (isotropic XY) and reading terms add in quadrature.
    expected = np.hypot(budget.combined("pose"), budget.combined("reading"))
    assert expected == pytest.approx(np.sqrt(0.010**2 + 0.005**2 * 2 + 0.010**2 + 0.04e-3**2
                                             + 0.19e-3**2 + 0.09e-3**2), rel=1e-12)
    assert np.std(r) == pytest.approx(expected, rel=0.03)
    assert np.mean(r) == pytest.approx(800.0, abs=4 * expected / np.sqrt(n))


def test_budget_k_divides():
    b = Budget(contributors=[Contributor("a", "x", 4.0, "um", 2.0, "B", "reading"),
                             Contributor("b", "y", 3.0, "um", 1.0, "A", "reading"),
                             Contributor("c", "z", 1.0, "mdeg", 1.0, "B", "beam_direction")])
    assert b.combined("reading") == pytest.approx(np.hypot(2e-3, 3e-3))
    assert b.combined("beam_direction") == pytest.approx(np.radians(1e-3))
    assert b.combined("pose") == 0.0


def test_displacement_model_jacobian():
    rng = np.random.default_rng(2)
    p, P, d0 = rng.normal(0, 300, (5, 2)), rng.normal(600, 100, (5, 2)), rng.normal(0, 10, 5)
    d, dd_dp, dd_dP = displacement_model(p, P, d0)
    h = 1e-6
    for c in range(2):
        e = np.zeros(2)
        e[c] = h
        assert (displacement_model(p + e, P, d0)[0] - d) / h == pytest.approx(dd_dp[:, c], abs=1e-6)
        assert (displacement_model(p, P + e, d0)[0] - d) / h == pytest.approx(dd_dP[:, c], abs=1e-6)


def test_beam_geometry_miss_sign_free():
    along, miss = beam_geometry(np.zeros((2, 2)), [0.0, 0.0], [[100.0, 1.0], [100.0, -1.0]])
    assert along == pytest.approx([100.0, 100.0]) and miss == pytest.approx([1.0, 1.0])
