"""Comparison references of 001 §3.2, simulated: 2D digital scale and linear laser interferometer.

They must reproduce the simulated truth within their stated uncertainty, and the plate's thermal model
must give 001's 3.6 µm per 100 mm. Units: mm, µm, °C.
"""

import dataclasses

import numpy as np
import pytest

from olti_drake.model.machine import VolumetricError, square_targets
from olti_drake.estimation.multilateration import align_to_commands
from olti_drake.sim.references import (DigitalScale, LinearInterferometer, line_errors, on_line, remove_offset,
                                   thermal_scale)

MACHINE = VolumetricError()
CMD = square_targets()
ACTUAL = MACHINE.actual(CMD)


def test_thermal_model_gives_the_papers_numbers():
    # 001 §3.2: plate α = 8e-6 /K calibrated at 20 °C, at 24.5 °C: 3.6 µm per 100 mm against the laser.
    assert DigitalScale().scale_difference_um(100.0) == pytest.approx(3.6, abs=0.001)
    assert thermal_scale(8e-6, 24.5) == pytest.approx(3.6e-5)
    # ... and the 2.5e-6 /K machine-plate mismatch: what the plate sees of the machine's own growth.
    assert 1e5 * thermal_scale(2.5e-6, 24.5) == pytest.approx(1.125)


def test_digital_scale_at_calibration_temperature_reproduces_the_truth():
    plate = DigitalScale(temperature_C=20.0)
    z = 1e3 * (plate.measure(ACTUAL, CMD, 1) - align_to_commands(ACTUAL, CMD)) / plate.std_um
    assert np.abs(z).max() < 4.0 and 0.6 < np.sqrt(np.mean(z ** 2)) < 1.4


def test_digital_scale_is_in_the_best_fit_gauge_whatever_its_mounting():
    a = DigitalScale(calibration_std_um=0.0, noise_um=0.0, mount_offset_mm=(0.0, 0.0), mount_angle_urad=0.0)
    b = dataclasses.replace(a, mount_offset_mm=(3.0, -2.0), mount_angle_urad=2000.0)
    np.testing.assert_allclose(a.measure(ACTUAL, CMD, 0), b.measure(ACTUAL, CMD, 0), atol=1e-9)
    err = a.measure(ACTUAL, CMD, 0) - CMD
    assert np.abs(err.mean(axis=0)).max() < 1e-12  # no mean translation from the commands


def test_warm_plate_reads_short_by_its_growth_and_compensation_removes_it():
    plate = DigitalScale(calibration_std_um=0.0, noise_um=0.0)  # 24.5 °C: 001's experiment
    truth = align_to_commands(ACTUAL, CMD)
    diff = 1e3 * (plate.measure(ACTUAL, CMD, 0) - truth)
    # Along Y = 0: the plate's E_XX falls 3.6 µm behind the truth's over the 100 mm.
    idx = on_line(CMD, "x", 0.0)
    assert diff[idx[-1], 0] - diff[idx[0], 0] == pytest.approx(-3.6, abs=0.01)
    idx = on_line(CMD, "y", 100.0)
    assert diff[idx[-1], 1] - diff[idx[0], 1] == pytest.approx(-3.6, abs=0.01)
    fixed = dataclasses.replace(plate, compensate=True).measure(ACTUAL, CMD, 0)
    np.testing.assert_allclose(fixed, truth, atol=1e-9)


@pytest.mark.parametrize("axis, at", [("x", 52.3), ("y", 71.3), ("x", 0.0)])
def test_linear_interferometer_within_table_1(axis, at):
    laser = LinearInterferometer(axis=axis, at_mm=at)
    s = np.arange(0.0, 101.0, 20.0)
    prof = laser.measure(MACHINE, s, 4)
    k = 0 if axis == "x" else 1
    c = laser.commands(s)
    e = 1e3 * (MACHINE.actual(c)[:, k] - c[:, k])
    truth = e - e[0]  # relative to the first point (ISO 230-2)
    assert prof.error_um[0] == 0.0
    # Table 1: ±(L·1e-7 + 0.005 µm); the 50 µrad misalignment adds well under a nm.
    assert np.all(np.abs(prof.error_um - truth) <= prof.bound_um + 1e-3)
    np.testing.assert_allclose(prof.bound_um, 1e-4 * s + 0.005)


def test_line_profiles_of_estimates():
    pos, e = line_errors(ACTUAL, CMD, "x", 0.0)
    np.testing.assert_allclose(pos, np.arange(0.0, 101.0, 20.0))
    np.testing.assert_allclose(e, 1e3 * (MACHINE.actual(np.column_stack([pos, 0 * pos]))[:, 0] - pos))
    pos, _ = line_errors(ACTUAL, CMD, "y", 100.0)
    np.testing.assert_allclose(pos, np.arange(0.0, 101.0, 20.0))
    assert remove_offset([1.0, 2.0, 3.0]) == pytest.approx([-1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="axis"):
        LinearInterferometer(axis="z").commands([0.0])
