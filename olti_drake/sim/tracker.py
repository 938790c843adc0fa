"""Simulated reference instrument: a laser tracker (paper 000, §4.3).

000 validates the identified model on the path X = 200 mm, Y = -500 ... 500 mm
with a Leica AT960-XR, U_xyz = ±15 µm + 6 µm/m. This module simulates that
instrument (reporting the *actual* end-effector position) and the path commands.

Units: mm and degrees at the Python API; SI (m, rad) on the Drake ports.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from olti_drake.model.errormap import approach_directions
from olti_drake.model.scara import DEG, forward_kinematics, inverse_kinematics
from olti_drake.sim.systems import set_default_name


@dataclass
class LaserTrackerSpec:
    """Laser tracker location and accuracy spec (AT960-XR of 000 §4.3).

    Fields (plain floats/lists, loadable with pydrake's ``yaml_load_typed``):
        position_mm: tracker location [x, y] in the robot frame, mm.
        u_const_um, u_per_m_um: the spec U(d) = u_const + u_per_m · d, µm, d in m.
        coverage_k: coverage factor of U.

    Interpretation: U(d) is the expanded (coverage k) uncertainty of the 3D
    point, i.e. of the length of the error vector. With independent,
    equal Gaussian errors per coordinate of standard deviation u, that length
    has RMS √3·u, so the per-coordinate standard uncertainty is
    u(d) = U(d) / (k √3). Only x and y are reported; d is the in-plane distance
    from the tracker to the point.
    """

    position_mm: List[float] = field(default_factory=lambda: [-1500.0, 0.0])
    u_const_um: float = 15.0
    u_per_m_um: float = 6.0
    coverage_k: float = 2.0

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field."""
        if np.shape(self.position_mm) != (2,) or not np.all(np.isfinite(self.position_mm)):
            raise ValueError(f"position_mm must be 2 finite numbers, got {self.position_mm!r}")
        for name in ("u_const_um", "u_per_m_um"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.coverage_k > 0:
            raise ValueError(f"coverage_k must be > 0, got {self.coverage_k!r}")

    def std_mm(self, p_mm) -> np.ndarray:
        """Per-coordinate standard uncertainty u(d) = U(d)/(k√3) in mm at points p (N, 2) mm."""
        self.validate()
        p = np.asarray(p_mm, dtype=float).reshape(-1, 2)
        d_m = np.hypot(*(p - np.asarray(self.position_mm, dtype=float)).T) * 1e-3
        return (self.u_const_um + self.u_per_m_um * d_m) / (self.coverage_k * np.sqrt(3.0)) * 1e-3


def measure_positions(p_actual_mm, spec: LaserTrackerSpec, rng) -> np.ndarray:
    """Tracker readings (N, 2) mm of actual positions (N, 2) or (2,) mm (000 §4.3).

    Adds independent Gaussian noise of std u(d) = U(d)/(k√3) per coordinate
    (see :class:`LaserTrackerSpec`), d = tracker-to-point distance in m.
    ``rng`` is a ``numpy.random.Generator`` or a seed.
    """
    p = np.asarray(p_actual_mm, dtype=float)
    if p.shape[-1:] != (2,) or p.ndim > 2:
        raise ValueError(f"p_actual_mm must have shape (2,) or (N, 2), got {p.shape}")
    p = p.reshape(-1, 2)
    u = spec.std_mm(p)
    return p + u[:, None] * np.random.default_rng(rng).standard_normal(p.shape)


def _pass_sequence(q: np.ndarray, overrun_deg: float) -> np.ndarray:
    """Joint sequence of one pass with an overrun pre-position before its first point."""
    steps = np.diff(q, axis=0)
    first = np.ones(q.shape[1])
    for a in range(q.shape[1]):  # direction of the first motion of each axis
        moving = np.flatnonzero(np.abs(steps[:, a]) > 1e-9)
        if moving.size:
            first[a] = np.sign(steps[moving[0], a])
    return np.vstack([q[0] - overrun_deg * first, q])


def path_commands(x_mm, y_mm, L1_mm, L2_mm, elbow: int = 1, bidirectional: bool = True,
                  overrun_deg: float = 2.0):
    """Commands and approach directions for a measured Cartesian path (000 §4.3).

    The XY command points (mm, e.g. X = 200, Y = -500 ... 500 of 000 Fig. 7)
    become (θ1*, θ2*) in deg by ``inverse_kinematics`` (nominal Eq. (3) of 000,
    L1, L2 in mm). The path is traversed forward and, if ``bidirectional``,
    backward. Each pass starts with an overrun move: the axes are first sent
    ``overrun_deg`` (deg) before the pass's first point, against each axis's
    first motion in the pass, so that the first point is approached in the
    direction of travel.

    Directions are **per axis** (``approach_directions`` of errormap, the Eq.
    (7) sign rule): a Cartesian path can reverse one axis mid-way (on X = 200
    the elbow J2 reverses at Y = 0), so dir1 and dir2 are not a single path
    direction.

    Returns:
        (theta1_deg, theta2_deg, dir1, dir2), each (N,) or (2N,) for the
        measured points (forward pass, then the return pass); use
        ``JointCommands(*path_commands(...))`` for the model.
    """
    x = np.atleast_1d(np.asarray(x_mm, dtype=float))
    y = np.atleast_1d(np.asarray(y_mm, dtype=float))
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"x_mm and y_mm must be 1-D of equal length, got {x.shape} and {y.shape}")
    if not overrun_deg > 0:
        raise ValueError(f"overrun_deg must be > 0, got {overrun_deg!r}")
    t1, t2 = inverse_kinematics(x, y, L1_mm, L2_mm, elbow=elbow)
    q = np.stack([t1, t2], axis=1)
    passes = [q, q[::-1]] if bidirectional else [q]
    seq, measured = [], []
    for p in passes:
        s = _pass_sequence(p, overrun_deg)
        measured.append(np.arange(1, len(s)) + sum(len(a) for a in seq))
        seq.append(s)
    seq = np.vstack(seq)
    idx = np.concatenate(measured)
    dirs = approach_directions(seq)[idx]
    cmd = seq[idx]
    return cmd[:, 0], cmd[:, 1], dirs[:, 0], dirs[:, 1]


class LaserTracker(LeafSystem):
    """Drake system: the laser tracker reading the actual end-effector position (000 §4.3).

    Input ``actual_joints`` (2): actual θ1, θ2 in **rad** (SI on ports).
    Output ``position`` (2): actual Eq. (3) of 000 with the *true* link lengths
    L1, L2 (mm, constructor) plus :func:`measure_positions` noise, in **m**.

    Noise is reproducible: a discrete-state sample counter n is incremented by
    a periodic update every ``period_s`` seconds (first at t = 0), and the
    output draws its noise from ``np.random.default_rng([seed, n])``, so
    re-evaluating the port gives the same value until the next update.
    """

    def __init__(self, spec: LaserTrackerSpec, L1_mm: float, L2_mm: float, seed: int,
                 period_s: float = 1.0):
        super().__init__()
        set_default_name(self)
        spec.validate()
        if int(seed) != seed or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        self._spec = dataclasses.replace(spec)
        self._L = (float(L1_mm), float(L2_mm))
        self._seed = int(seed)
        self.DeclareVectorInputPort("actual_joints", 2)
        self._counter = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._tick)
        self.DeclareVectorOutputPort("position", 2, self._calc_position,
                                     prerequisites_of_calc={self.all_input_ports_ticket(),
                                                            self.xd_ticket()})

    def _tick(self, context, discrete_state):
        discrete_state.set_value(self._counter, context.get_discrete_state(self._counter).value() + 1)

    def _calc_position(self, context, output: BasicVector):
        q = self.get_input_port(0).Eval(context)
        n = int(context.get_discrete_state(self._counter).value()[0])
        p, _ = forward_kinematics(q[0] / DEG, q[1] / DEG, *self._L)
        meas = measure_positions(p, self._spec, np.random.default_rng([self._seed, n]))
        output.SetFromVector(meas[0] * 1e-3)
