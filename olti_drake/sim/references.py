"""Comparison references of 001 §3.2, simulated: a 2D digital scale (Figs. 10, 12) and a linear laser
interferometer (Fig. 13).

Both read the machine's *actual* positions, :meth:`VolumetricError.actual
<olti_drake.model.machine.VolumetricError.actual>` -- the machine in its thermal
state at the measurement temperature (its own thermal expansion is part of its
E_XX, E_YY) -- and report them the way the multilateration result can be
compared with:

* :class:`DigitalScale` -- a grid plate (KGM 182-like) on the table: the 2D
  positions of the targets with its calibration error and its thermal
  expansion, moved into the multilateration's ``best-fit`` gauge
  (:func:`~olti_drake.estimation.multilateration.align_to_commands`: the plate's
  placement on the table is unknown and a rigid motion; its scale is not).
* :class:`LinearInterferometer` -- a laser interferometer aligned to X (at a
  given Y) or to Y (at a given X): the linear positioning error E_XX or E_YY
  along its line relative to the first point (ISO 230-2), with 001 Table 1's
  uncertainty ±(L·1e-7 + 0.005 µm). Compare shapes: remove the offset of both
  (:func:`remove_offset`), since the gauge fixes no point of a line.

Thermal model (001 §3.2). The plate is calibrated at T_cal = 20 °C; at T its
grid has grown by α_p (T − T_cal), so it reads a true length ℓ as
ℓ / (1 + α_p (T − T_cal)). The laser interferometer is compensated for the air
and reads true length. The plate therefore reads α_p (T − T_cal) ℓ shorter than
the laser: 8e-6 /K × 4.5 K × 100 mm = 3.6 µm per 100 mm at 24.5 °C, 001's
number. A machine whose uncompensated scales grow with α_m moves α_m ΔT ℓ
farther than commanded: the laser sees that whole growth, the plate only
(α_m − α_p) ΔT ℓ (001: 2.5e-6 /K apart, 1.1 µm per 100 mm) -- here that growth
is inside the machine truth.

Units: mm, µm for errors, °C, 1/K.
"""

from dataclasses import dataclass, field
from typing import Tuple

import numpy as np

from olti_drake.model.instrument import InterferometerOptions, beam_geometry, quantize
from olti_drake.estimation.multilateration import align_to_commands

#: 001 §3.2: the machine's temperature during the experiment, °C.
PAPER001_TEMPERATURE_C = 24.5


def thermal_scale(alpha_per_K: float, temperature_C: float, calibration_temperature_C: float = 20.0) -> float:
    """Relative growth α (T − T_cal) of a scale calibrated at T_cal (dimensionless)."""
    return alpha_per_K * (temperature_C - calibration_temperature_C)


@dataclass
class DigitalScale:
    """A 2D digital scale (grid plate, KGM 182-like; 001 §3.2, Fig. 12) on the machine table.

    ``alpha_per_K``: the plate's expansion coefficient (8e-6 /K, 001); the plate at ``temperature_C``
    (that of the machine, 001), calibrated at ``calibration_temperature_C``. ``calibration_std_um``:
    its residual grid error after calibration, per axis (k = 1); ``noise_um``: reading noise per
    axis. ``mount_offset_mm``, ``mount_angle_urad``: where the plate's frame sits on the table
    (unknown to the comparison: removed by the best-fit gauge). ``compensate``: correct the readings
    for the plate's growth with the nominal α and T (001 did not).
    """

    alpha_per_K: float = 8e-6
    temperature_C: float = PAPER001_TEMPERATURE_C
    calibration_temperature_C: float = 20.0
    calibration_std_um: float = 0.3
    noise_um: float = 0.02
    mount_offset_mm: Tuple[float, float] = (0.4, -0.3)
    mount_angle_urad: float = 150.0
    compensate: bool = False

    @property
    def growth(self) -> float:
        """The plate's relative growth α_p (T − T_cal)."""
        return thermal_scale(self.alpha_per_K, self.temperature_C, self.calibration_temperature_C)

    @property
    def std_um(self) -> float:
        """Stated standard uncertainty per axis (k = 1), µm: calibration and noise (not the thermal scale,
        a systematic error the comparison shows, unless ``compensate``)."""
        return float(np.hypot(self.calibration_std_um, self.noise_um))

    def scale_difference_um(self, length_mm: float = 100.0) -> float:
        """How much shorter than the laser the plate reads ``length_mm``, µm (001: 3.6 µm per 100 mm)."""
        return 1e3 * length_mm * self.growth / (1 + self.growth)

    def measure(self, actual_mm, commands_mm, rng) -> np.ndarray:
        """Plate readings (N, 2) mm of the actual positions, in the best-fit gauge of the commands.

        The calibration error is drawn once per grid position (a property of the plate), the noise
        per reading, both from ``rng`` (seed or Generator).
        """
        rng = np.random.default_rng(rng)
        a = 1e-6 * self.mount_angle_urad
        R = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])  # machine -> plate frame
        plate = (np.asarray(actual_mm, dtype=float) - np.asarray(self.mount_offset_mm)) @ R.T
        plate = plate / (1 + self.growth)  # the grown grid counts fewer periods over the same length
        plate = plate + 1e-3 * (self.calibration_std_um * rng.standard_normal(plate.shape)
                                + self.noise_um * rng.standard_normal(plate.shape))
        if self.compensate:
            plate = plate * (1 + self.growth)
        return align_to_commands(plate, commands_mm)


# -- linear laser interferometer, 001 Fig. 13 -----------------------------------------------------------
@dataclass
class LinearProfile:
    """A linear positioning error along a line: command positions (mm), E relative to the first point
    (µm), and the ± bound of 001 Table 1 at each point (µm)."""

    position_mm: np.ndarray
    error_um: np.ndarray
    bound_um: np.ndarray


@dataclass
class LinearInterferometer:
    """A laser interferometer aligned to one machine axis (001 §3.2, Fig. 13; Table 1).

    ``axis``: ``x`` or ``y``, measured along the line where the other coordinate is ``at_mm``
    (001: Y = 52.3 mm for X, X = 71.3 mm for Y). ``misalignment_urad``: the beam's angle to the
    axis (cosine error). Table 1: ±(L·``relative`` + ``constant_um``) -- the scale term drawn once
    per measurement (rectangular), the constant term is the counter's λ/64 resolution.
    """

    axis: str = "x"
    at_mm: float = 0.0
    misalignment_urad: float = 50.0
    relative: float = 1e-7
    constant_um: float = 0.005
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)

    def commands(self, positions_mm) -> np.ndarray:
        """Command positions (N, 2) mm of the line at ``positions_mm`` (N,) along the axis."""
        s = np.asarray(positions_mm, dtype=float)
        other = np.full_like(s, self.at_mm)
        if self.axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y', got {self.axis!r}")
        return np.column_stack([s, other] if self.axis == "x" else [other, s])

    def bound_um(self, length_mm) -> np.ndarray:
        """001 Table 1: ±(L·1e-7 + 0.005 µm) for the measured length L (mm), µm."""
        return 1e3 * self.relative * np.abs(np.asarray(length_mm, dtype=float)) + self.constant_um

    def measure(self, machine, positions_mm, rng) -> LinearProfile:
        """E_XX or E_YY (µm) of ``machine`` at ``positions_mm`` along the line, relative to the first point."""
        rng = np.random.default_rng(rng)
        s = np.asarray(positions_mm, dtype=float)
        actual = machine.actual(self.commands(s))
        k = 0 if self.axis == "x" else 1
        angle = (0.0 if k == 0 else 90.0) + np.degrees(1e-6 * self.misalignment_urad)
        u = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
        origin = actual[0] - 300.0 * u  # the laser head 300 mm before the first point, on its beam
        along, _ = beam_geometry(origin, angle, actual)
        reading = (along - along[0]) * (1 + self.relative * rng.uniform(-1, 1))
        reading = quantize(reading, self.interferometer.resolution_mm)
        return LinearProfile(s, 1e3 * (reading - (s - s[0])), self.bound_um(s - s[0]))


def remove_offset(error_um) -> np.ndarray:
    """A positioning-error profile without its mean: the shape, as a line in the best-fit gauge shows it."""
    e = np.asarray(error_um, dtype=float)
    return e - e.mean()


def on_line(commands_mm, axis: str, at_mm: float, tol_mm: float = 1e-9) -> np.ndarray:
    """Indices of the commands on the line ``axis`` at ``at_mm`` (the other coordinate), sorted along it."""
    c = np.asarray(commands_mm, dtype=float)
    k = {"x": 0, "y": 1}[axis]
    idx = np.flatnonzero(np.abs(c[:, 1 - k] - at_mm) <= tol_mm)
    return idx[np.argsort(c[idx, k])]


def line_errors(points_mm, commands_mm, axis: str, at_mm: float):
    """(positions (n,) mm, E (n,) µm) of estimated points along a line of commands: E_XX = x − x* on a
    line along X, E_YY = y − y* along Y (001 Fig. 13 from Fig. 10)."""
    c = np.asarray(commands_mm, dtype=float)
    idx = on_line(c, axis, at_mm)
    k = {"x": 0, "y": 1}[axis]
    return c[idx, k], 1e3 * (np.asarray(points_mm, dtype=float)[idx, k] - c[idx, k])
