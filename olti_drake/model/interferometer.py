"""The laser interferometer reading: measurement model (000 Eq. 5, 10; §5).

Units: mm and degrees at the API.

Two levels, sharing this module:

* :func:`displacement_model` -- the identification model of Eq. (5)/(10):
  d = ‖p − P_j‖ − d0_j, with its analytic Jacobians.
* :func:`simulate_readings` -- what the instrument reports in simulation: the
  beam leaves the laser head at ``origin`` along ``beam_angle``; a cat's eye
  returns the optical length of the beam up to the point nearest its centre,
  (P − o)·u, i.e. the true distance times the cosine of the aiming error
  ("cosine error", 000 §5); the beam is lost when it misses the centre by more
  than the acceptance (1 mm in 000 §5); noise from the budget (000 Table 2);
  counter resolution λ/64.
"""


from dataclasses import dataclass

import numpy as np

from olti_drake.io.budget import Budget


@dataclass
class InterferometerOptions:
    """Switchable terms of the simulated interferometer (YAML-loadable).

    ``beam_direction_noise`` is off by default: 000 Table 2's u31/u32 are the
    beam-direction effect of the J1/J2 deviations and of the reflector estimate
    error, which the simulator already models physically; switching it on adds
    them again as random aiming noise.
    """

    wavelength_nm: float = 632.8
    resolution_divisor: float = 64.0
    acceptance_mm: float = 1.0
    noise: bool = True
    quantization: bool = True
    cosine_error: bool = True
    beam_loss: bool = True
    beam_direction_noise: bool = False

    @property
    def resolution_mm(self) -> float:
        """Counter resolution λ/divisor, mm (λ/64 ≈ 9.9 nm for HeNe)."""
        return self.wavelength_nm * 1e-6 / self.resolution_divisor

    def validate(self, where: str = "interferometer") -> "InterferometerOptions":
        for key in ("wavelength_nm", "resolution_divisor", "acceptance_mm"):
            v = getattr(self, key)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{where}.{key} must be finite and > 0, got {v!r}")
        return self


def displacement_model(p_mm, reflector_mm, dead_path_mm):
    """Predicted reading d = ‖p − P‖ − d0 and its Jacobians (Eq. (5)/(10) of 000).

    Args:
        p_mm: (N, 2) end-effector positions, mm.
        reflector_mm: (N, 2) reflector position of each reading, mm.
        dead_path_mm: (N,) dead path of each reading's reflector, mm.

    Returns:
        d (N,), dd/dp (N, 2) = u, dd/dP (N, 2) = −u, with u the unit vector
        from P to p (dd/dd0 = −1).
    """
    diff = np.asarray(p_mm, dtype=float) - np.asarray(reflector_mm, dtype=float)
    dist = np.hypot(diff[:, 0], diff[:, 1])
    if np.any(dist == 0):
        raise ValueError(f"end effector coincides with its reflector at reading {np.flatnonzero(dist == 0)[0]}")
    u = diff / dist[:, None]
    return dist - np.asarray(dead_path_mm, dtype=float), u, -u


def beam_geometry(origin_mm, beam_angle_deg, reflector_mm):
    """Optical length to the cat's eye and the beam's miss of its centre, mm.

    Returns (along, miss): along = (P − o)·u (the length the interferometer
    sees, the cosine error included), miss = |(P − o) × u| (lateral distance of
    the reflector centre from the beam line), for u = (cos a, sin a).
    """
    rel = np.asarray(reflector_mm, dtype=float) - np.asarray(origin_mm, dtype=float)
    a = np.radians(beam_angle_deg)
    c, s = np.cos(a), np.sin(a)
    return rel[..., 0] * c + rel[..., 1] * s, np.abs(rel[..., 1] * c - rel[..., 0] * s)


def quantize(x_mm, step_mm):
    """Counter quantization: round to the nearest multiple of ``step_mm``."""
    return np.round(np.asarray(x_mm) / step_mm) * step_mm


def simulate_readings(origin_mm, beam_angle_deg, reflector_mm, dead_path_mm,
                      options: InterferometerOptions, budget: Budget, rng: np.random.Generator):
    """Simulated readings of an open-loop steered interferometer (000 §2, §5).

    Args:
        origin_mm: (N, 2) actual laser head positions (beam origin), mm.
        beam_angle_deg: (N,) actual world beam direction, deg.
        reflector_mm: (N, 2) true reflector centres, mm.
        dead_path_mm: (N,) counter zero of each reading's reflector, mm.
        options: which terms are on, resolution, acceptance.
        budget: standard deviations of the white-noise terms (``pose``,
            ``reading``, ``beam_direction`` contributors, root-sum-squared).
        rng: random generator; four normals are drawn per reading whatever the
            switches, so switching one term does not change the others.

    Returns:
        (reading_mm (N,), valid (N,) bool, miss_mm (N,)).
    """
    origin = np.atleast_2d(np.asarray(origin_mm, dtype=float))
    angle = np.atleast_1d(np.asarray(beam_angle_deg, dtype=float))
    z = rng.standard_normal((len(origin), 4))
    if options.noise:
        origin = origin + budget.combined("pose") * z[:, :2]
        if options.beam_direction_noise:
            angle = angle + np.degrees(budget.combined("beam_direction")) * z[:, 2]
    along, miss = beam_geometry(origin, angle, reflector_mm)
    length = along if options.cosine_error else np.hypot(along, miss)
    reading = length - np.asarray(dead_path_mm, dtype=float)
    if options.noise:
        reading = reading + budget.combined("reading") * z[:, 3]
    if options.quantization:
        reading = quantize(reading, options.resolution_mm)
    valid = ~(options.beam_loss & (miss > options.acceptance_mm))
    return reading, valid, miss
