"""Initial estimation of a station's rotation centre and zero angle (001 §2.2, Figs. 6-7), simulated.

Before the multilateration (001 §2.3) every station -- the rotary table that
carries the interferometer -- needs two rough values:

* the position P*_j of the table axis average line in the machine frame,
  which Eq. (1) of 001 aims from and the multilateration starts from
  (:class:`~olti_drake.estimation.multilateration.MultilaterationOptions` ``stations_mm``);
* the zero angle: the table angle at which the beam is normal to the
  machine's Y-axis reference straight line, which turns Eq. (1)'s world
  angle into a table command.

Both are simulated as the operator performs them, on a true
:class:`RotaryStation` and the true machine
(:class:`~olti_drake.model.machine.VolumetricError`), with the readings of
:func:`~olti_drake.model.instrument.simulate_readings` (projection on the beam,
cosine error, beam loss, λ/64, budget noise of 001 Table 4).

* :func:`estimate_rotation_centre` (Fig. 6): the cat's eye near the axis, the
  table turning, the reading varies with the target's offset δ from the axis
  as δ·u(θ) (first harmonic; the beam's lateral offset from the axis does not
  enter the projection, the radial error motion adds higher harmonics and
  noise). The operator fits the first harmonic and moves the machine by it
  until it vanishes; the command position is then P*_j. Its error is the
  machine's positioning error there (the machine puts the target at
  actual(command), not at the command) plus the fit's noise: of the order of
  001's 11.5 µm (k = 2).
* :func:`estimate_zero_angle` (Fig. 7): the table held, the beam roughly along
  ±X, the target moved along Y across the beam; the reading's slope along Y is
  the beam's angle to the normal of the Y motion; the operator turns the table
  (in encoder pulses, 001 Table 2) until the slope vanishes. The reference
  straight line is the least-squares line of the Y motion over the travel the
  procedure uses (ISO 230-1). The travel is limited by the cat's eye
  acceptance (the beam is lost beyond it), which with 001 Table 4's reading
  noise leaves tens of µrad; the encoder's resolution 2π/655360 alone, as a
  rectangular distribution, is 2.8 µrad -- 001's u41 value. Either way the
  zero angle only tilts the beam: a cosine error (001 §4.3).

Units: mm, µm for errors of positions, deg at the table interface, rad/µrad for the zero angle.
"""

from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from olti_drake.model.budget import Budget
from olti_drake.model.instrument import InterferometerOptions, simulate_readings

#: Encoder pulses per revolution of the rotary table RT158A (001 Table 2).
ENCODER_PULSES = 655360
#: One encoder pulse, rad (9.6 µrad); its rectangular standard uncertainty is PULSE_RAD/√12 = 2.8 µrad.
PULSE_RAD = 2 * np.pi / ENCODER_PULSES


@dataclass
class RotaryStation:
    """The true station: the table axis and how the interferometer sits on the table (mm, deg, µm).

    ``axis_mm``: the axis average line in the machine command frame (the truth P_j).
    ``head_distance_mm``: the beam origin lies this far behind the axis, along the beam.
    ``beam_offset_mm``: lateral distance of the beam line from the axis (001 §2.1: "approximately
    intersects"). ``mount_deg``: world beam angle at table angle 0 (what the zero angle finds).
    ``radial_motion_um``: synchronous radial error motion of the axis along the beam, amplitudes of
    its harmonics 2, 3, ... per revolution (the first harmonic is the centring, by definition of the
    axis average line; the random part is the budget's u21).
    """

    axis_mm: Tuple[float, float] = (0.0, 0.0)
    head_distance_mm: float = 60.0
    beam_offset_mm: float = 0.2
    mount_deg: float = 0.7
    radial_motion_um: Tuple[float, ...] = (0.6, 0.3)

    def beam(self, table_rad):
        """Beam origins (N, 2) mm and world beam angles (N,) deg at actual table angles (N,) rad."""
        t = np.atleast_1d(np.asarray(table_rad, dtype=float))
        world = t + np.radians(self.mount_deg)
        u = np.column_stack([np.cos(world), np.sin(world)])
        n = np.column_stack([-u[:, 1], u[:, 0]])
        # Harmonic n = k + 2 with an arbitrary fixed phase k rad: repeatable from revolution to revolution.
        motion = sum(1e-3 * a * np.cos((k + 2) * t + k) for k, a in enumerate(self.radial_motion_um))
        along = motion - self.head_distance_mm
        origin = np.asarray(self.axis_mm, dtype=float) + along[:, None] * u + self.beam_offset_mm * n
        return origin, np.degrees(world)


def _read(station, machine, commands_mm, table_rad, budget, rng, interferometer, what):
    """Readings (N,) mm of the targets at ``commands_mm`` (N, 2) with the table at ``table_rad`` (N,)."""
    origin, angle = station.beam(table_rad)
    actual = machine.actual(commands_mm)
    reading, valid, miss = simulate_readings(origin, angle, actual, station.head_distance_mm, interferometer,
                                             budget, rng)
    if not valid.all():
        raise ValueError(f"{what}: the beam misses the cat's eye by {miss.max():.3f} mm (acceptance "
                         f"{interferometer.acceptance_mm:g} mm): start closer to the beam")
    return reading


def _line_fit(A, b):
    """Least-squares coefficients of b ≈ A c and their covariance from the residual variance."""
    c, *_ = np.linalg.lstsq(A, b, rcond=None)
    dof = max(len(b) - A.shape[1], 1)
    s2 = np.sum((b - A @ c) ** 2) / dof
    return c, s2 * np.linalg.inv(A.T @ A)


def positioning_accuracy_um(machine, points_mm, margin_mm: float = 20.0, step_mm: float = 5.0) -> float:
    """The machine's positioning accuracy over the box around ``points_mm`` (N, 2): max |actual − command|
    of either axis, µm -- the bound an operator takes from the machine's acceptance test (ISO 230-2)."""
    p = np.asarray(points_mm, dtype=float)
    lo, hi = p.min(axis=0) - margin_mm, p.max(axis=0) + margin_mm
    X, Y = np.meshgrid(np.arange(lo[0], hi[0] + step_mm, step_mm), np.arange(lo[1], hi[1] + step_mm, step_mm))
    c = np.column_stack([X.ravel(), Y.ravel()])
    return float(1e3 * np.max(np.abs(machine.actual(c) - c)))


# -- rotation centre, 001 Fig. 6 -----------------------------------------------------------------------
@dataclass
class CentreOptions:
    """How the operator centres the target (001 §2.2, Fig. 6).

    ``n_angles`` readings over one table revolution; ``zero_rough_deg``: the operator's rough world beam
    angle at table 0 (the fitted offset is rotated by its error: iterations absorb it); stop when the fitted
    offset is below ``tolerance_um``; machine moves in steps of ``command_resolution_mm``;
    ``machine_accuracy_um``: ± bound of the machine's positioning error near the station (type B,
    rectangular; see :func:`positioning_accuracy_um`), which the estimate inherits.
    """

    n_angles: int = 72
    zero_rough_deg: float = 0.0
    tolerance_um: float = 0.3
    max_iterations: int = 8
    command_resolution_mm: float = 1e-4
    machine_accuracy_um: float = 10.0


@dataclass
class CentreEstimate:
    """P*_j (mm, machine command frame), its error from the true axis (µm), standard uncertainty per axis
    (µm, k = 1), the sweeps (table angle deg, reading µm) of every iteration."""

    estimate_mm: np.ndarray
    error_um: np.ndarray
    std_um: np.ndarray
    iterations: int
    sweeps: List[tuple] = field(default_factory=list)

    @property
    def expanded_um(self) -> np.ndarray:
        """U (k = 2) per axis, µm (001 §4.3: 11.5 µm)."""
        return 2 * self.std_um


def estimate_rotation_centre(station: RotaryStation, machine, start_mm, budget: Budget, rng,
                             options: Optional[CentreOptions] = None,
                             interferometer: Optional[InterferometerOptions] = None) -> CentreEstimate:
    """Simulated centring of 001 Fig. 6: the table axis P*_j from the target position of least variation.

    ``start_mm``: the command where the operator first puts the target "approximately on the axis" (within
    the cat's eye acceptance). Each iteration sweeps the table through a revolution, fits
    d(θ) = c + δ·u(θ̂) (u the beam direction from the rough zero) and moves the target by −δ. The estimate
    is the last command minus the last fitted δ. Its standard uncertainty per axis combines the fit (type A)
    and the machine's positioning accuracy (type B, rectangular): the machine puts the target at
    actual(command), so the command of the centred target is off by the positioning error there.
    """
    o = options or CentreOptions()
    opts = interferometer or InterferometerOptions()
    rng = np.random.default_rng(rng)
    table = np.linspace(0.0, 2 * np.pi, o.n_angles, endpoint=False)
    beam = table + np.radians(o.zero_rough_deg)
    A = np.column_stack([np.ones_like(beam), np.cos(beam), np.sin(beam)])
    cmd = np.asarray(start_mm, dtype=float)
    sweeps = []
    for it in range(1, o.max_iterations + 1):
        d = _read(station, machine, np.tile(cmd, (o.n_angles, 1)), table, budget, rng, opts, "centring")
        sweeps.append((np.degrees(table), 1e3 * (d - d.mean())))
        c, cov = _line_fit(A, d)
        delta = c[1:]
        if 1e3 * np.hypot(*delta) < o.tolerance_um:
            break
        # The operator moves the target against the offset, in the machine's command steps.
        cmd = np.round((cmd - delta) / o.command_resolution_mm) * o.command_resolution_mm
    estimate = cmd - delta
    std = np.sqrt(1e6 * np.diag(cov)[1:] + o.machine_accuracy_um ** 2 / 3)
    return CentreEstimate(estimate, 1e3 * (estimate - np.asarray(station.axis_mm)), std, it, sweeps)


# -- zero angle, 001 Fig. 7 -----------------------------------------------------------------------------
@dataclass
class ZeroAngleOptions:
    """How the operator aligns the beam normal to the Y-axis reference line (001 §2.2, Fig. 7).

    ``target_distance_mm``: signed X distance from the axis to the Y line the target moves on (negative:
    the beam points to −X). ``travel_mm``: Y travel across the beam, centred on it (the cat's eye returns
    the beam within the interferometer's acceptance only); ``n_points`` readings over it (continuous
    logging). ``rough_error_mrad``: error of the operator's first table setting.
    """

    target_distance_mm: float = 150.0
    travel_mm: float = 1.6
    n_points: int = 161
    rough_error_mrad: float = 2.0
    max_iterations: int = 6


@dataclass
class ZeroAngleEstimate:
    """The zero angle (rad, continuous encoder scale), its error from the true zero (rad), standard
    uncertainty (rad, k = 1), the tilt of the Y reference line's normal in the command frame (rad; the aim
    of Eq. (1) is off by error + tilt), and the sweeps (Y command mm, reading µm)."""

    estimate_rad: float
    error_rad: float
    std_rad: float
    reference_tilt_rad: float
    iterations: int
    sweeps: List[tuple] = field(default_factory=list)


def _reference_tilt(machine, x_mm, y_mm) -> float:
    """Angle (rad) of the normal to the Y motion's least-squares line (ISO 230-1) at command X = x_mm."""
    actual = machine.actual(np.column_stack([np.full(len(y_mm), x_mm), y_mm]))
    slope = np.polyfit(actual[:, 1], actual[:, 0], 1)[0]  # dx/dy of the actual path
    return float(-np.arctan(slope))


def estimate_zero_angle(station: RotaryStation, machine, budget: Budget, rng,
                        options: Optional[ZeroAngleOptions] = None,
                        interferometer: Optional[InterferometerOptions] = None) -> ZeroAngleEstimate:
    """Simulated zero-angle alignment of 001 Fig. 7 (rad).

    The table is set in whole encoder pulses (001 Table 2); the servo holds it within one pulse (rectangular).
    With the table at rest the radial error motion does not change, so only the budget's ``reading``
    contributors add noise. Per iteration: sweep the target along Y across the beam, fit the slope s of the
    reading along Y (the beam's angle to the normal of the Y motion), turn the table by −s in whole pulses;
    stop when that is under one pulse or within twice the slope's standard uncertainty. The estimate is the
    encoder angle minus the last slope. Its standard uncertainty combines the slope fit (type A) and the
    encoder quantization (PULSE_RAD/√12).
    """
    o = options or ZeroAngleOptions()
    opts = interferometer or InterferometerOptions()
    rng = np.random.default_rng(rng)
    still = Budget(budget.name + " (table at rest: reading terms)", budget.source,
                   [c for c in budget.contributors if c.acts_on == "reading"])
    facing = 0.0 if o.target_distance_mm >= 0 else np.pi  # beam toward +X or −X
    sign = 1.0 if facing == 0.0 else -1.0
    x_line = station.axis_mm[0] + o.target_distance_mm
    mount = np.radians(station.mount_deg)
    rough = facing - mount + 1e-3 * o.rough_error_mrad
    pulses = int(np.round(rough / PULSE_RAD))
    offsets = np.linspace(-o.travel_mm / 2, o.travel_mm / 2, o.n_points)
    sweeps = []
    for it in range(1, o.max_iterations + 1):
        table = pulses * PULSE_RAD + PULSE_RAD * rng.uniform(-0.5, 0.5)  # the servo rests within a pulse
        origin, angle = station.beam([table])
        # The operator puts the target on the beam (where the return signal is), then sweeps Y across it.
        y_beam = origin[0, 1] + (x_line - origin[0, 0]) * np.tan(np.radians(angle[0]))
        y = y_beam + offsets
        cmd = np.column_stack([np.full(o.n_points, x_line), y])
        d = _read(station, machine, cmd, np.full(o.n_points, table), still, rng, opts, "zero-angle sweep")
        sweeps.append((y, 1e3 * (d - d.mean())))
        c, cov = _line_fit(np.column_stack([np.ones_like(y), y - y.mean()]), d)
        slope = sign * c[1]  # the beam's angle to the normal of the Y motion (small)
        turn = int(np.round(np.arcsin(slope) / PULSE_RAD))
        if turn == 0 or abs(slope) < 2 * np.sqrt(cov[1, 1]):  # nothing left the noise would not hide
            break
        pulses -= turn
    estimate = pulses * PULSE_RAD - np.arcsin(slope) - facing
    tilt = _reference_tilt(machine, x_line, y)
    truth = tilt - mount  # the continuous encoder angle at which the beam is along the reference normal
    std = float(np.sqrt(cov[1, 1] + PULSE_RAD ** 2 / 12))
    return ZeroAngleEstimate(float(estimate), float(estimate - truth), std, tilt, it, sweeps)
