"""Measurement plans for a SCARA campaign (paper 000 §4.1, Eq. (11)-(12)).

A plan is the ordered sequence of commanded joint moves (θ1*, θ2*), in
**degrees**, each flagged ``measure`` (an interferometer reading is taken) or
not (a pass-through move: the first approach, or an overrun past a turnaround
so that the next measured pose is approached from the intended side). The same
plan is run once per reflector position, so it has no reflector column.

Approach directions are not stored: they follow from the move sequence by the
rule of Eq. (7) of 000 (:func:`olti_drake.model.errormap.approach_directions`).
The first row is where the robot starts (the first approach is part of the plan).

Plan files (CSV, or a YAML :class:`BidirectionalGrid` mapping) are read and written by
:mod:`olti_drake.io.plan_io`.
"""

# No "from __future__ import annotations": pydrake yaml_load_typed reads the
# dataclass field types, and string annotations break it.
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from olti_drake.model.errormap import MOTION_TOLERANCE_DEG, approach_directions
from olti_drake.units import unit_bound

#: Tolerance (deg) for "step divides the range".
STEP_TOLERANCE_DEG = 1e-9
#: Most measured poses of a generated plan (1000 x 1000): beyond it a step is a slip (a step in the wrong
#: unit) that would build a plan of gigabytes; refused, naming the step, before anything is allocated.
MAX_PLAN_POSES = 1_000_000


class MeasuredPoses(NamedTuple):
    """The measured rows of a plan: row indices into the plan, angles (deg), directions (±1)."""

    index: np.ndarray
    theta1_deg: np.ndarray
    theta2_deg: np.ndarray
    dir1: np.ndarray
    dir2: np.ndarray


@dataclass(frozen=True, eq=False)
class Plan:
    """Ordered commanded moves (θ1*, θ2*) in degrees with a measure flag (000 §4.1).

    ``theta1_deg``, ``theta2_deg``: (K,) commanded angles, deg, in the order
    they are executed; row 0 is the starting position. ``measure``: (K,) bool,
    True where an interferometer reading is taken.
    """

    theta1_deg: np.ndarray
    theta2_deg: np.ndarray
    measure: np.ndarray

    def __post_init__(self):
        # Copies, so freezing them below does not touch the caller's arrays.
        t1 = np.array(self.theta1_deg, dtype=float)
        t2 = np.array(self.theta2_deg, dtype=float)
        m = np.array(self.measure)
        if not (t1.ndim == t2.ndim == m.ndim == 1):
            raise ValueError("plan: theta1_deg, theta2_deg and measure must be 1-D arrays")
        if not (t1.size == t2.size == m.size):
            raise ValueError(f"plan: theta1_deg has {t1.size} rows, theta2_deg {t2.size}, "
                             f"measure {m.size}; they must be equal")
        for key, v in (("theta1_deg", t1), ("theta2_deg", t2)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"plan: {key} row {int(np.argmin(np.isfinite(v)))} is not finite")
        if m.dtype != bool:
            if not np.all(np.isin(m, (0, 1))):
                raise ValueError("plan: measure must be 0/1 or bool")
            m = m.astype(bool)
        if not m.any():
            raise ValueError("plan: no measured row (measure is 0 everywhere)")
        for key, v in (("theta1_deg", t1), ("theta2_deg", t2), ("measure", m)):
            v.setflags(write=False)  # frozen means frozen: no in-place edits
            object.__setattr__(self, key, v)

    def __len__(self) -> int:
        return self.theta1_deg.size

    @property
    def n_measured(self) -> int:
        """Number of measured rows (000 §4.1: N = 352 for the paper's plan)."""
        return int(np.count_nonzero(self.measure))

    def directions(self) -> np.ndarray:
        """(K, 2) approach directions (±1) of J1, J2 at every row (formats.md rule).

        Row 0 is the starting position: before it both axes count as +1.
        """
        return approach_directions(np.column_stack([self.theta1_deg, self.theta2_deg]),
                                   last_direction=1.0)

    def measured(self) -> MeasuredPoses:
        """The measured rows only: indices, θ1*, θ2* (deg), dir1, dir2 (±1)."""
        idx = np.flatnonzero(self.measure)
        d = self.directions()[idx]
        return MeasuredPoses(idx, self.theta1_deg[idx], self.theta2_deg[idx], d[:, 0], d[:, 1])


# ---------------------------------------------------------------------------
# Bidirectional grid (000 §4.1, Eq. (11)-(12))


def _sweep(start: float, stop: float, step: float, name: str):
    """Out-and-back values start..stop..start (deg) and their directions of travel."""
    for key, v in ((f"{name}_start", start), (f"{name}_stop", stop), (f"{name}_step", step)):
        if not (math.isfinite(v) and abs(v) <= unit_bound("_deg")):
            raise ValueError(f"{key} must be finite and within +-{unit_bound('_deg'):g} deg, got {v!r}")
    if step <= 0:
        raise ValueError(f"{name}_step must be > 0 deg, got {step:g}")
    span = abs(stop - start)
    if span / step + 1 > MAX_PLAN_POSES:
        raise ValueError(f"{name}_step = {step:g} deg gives {span / step + 1:.3g} values over {span:g} deg, "
                         f"more than {MAX_PLAN_POSES:,} (use a coarser step)")
    n = round(span / step)
    if abs(span - n * step) > STEP_TOLERANCE_DEG:
        raise ValueError(f"{name}_step = {step:g} deg does not divide "
                         f"|{name}_stop - {name}_start| = {span:g} deg")
    out = -1.0 if stop < start else 1.0  # a single-point sweep goes out positive
    vals = start + out * step * np.arange(n + 1)
    vals[-1] = stop
    return np.concatenate([vals, vals[::-1]]), np.repeat([out, -out], n + 1)


def bidirectional_grid(theta1_start: float = -140.0, theta1_stop: float = 60.0,
                       theta1_step: float = 20.0, theta2_start: float = 0.0,
                       theta2_stop: float = 140.0, theta2_step: float = 20.0,
                       overrun_deg: float = 2.0) -> Plan:
    """The paper's bidirectional pattern (000 §4.1, Eq. (11)-(12)), all in degrees.

    θ1* goes start→stop then stop→start (Eq. (12)); at each θ1* value θ2*
    goes start→stop→start (Eq. (11)). Every listed value is a measured pose,
    approached on both axes from its sweep's direction of travel: the "out"
    direction is sign(stop − start), the way back the opposite. Where the
    previous move would leave the wrong direction (the start, a turnaround,
    θ2* restarting its sweep), one unmeasured row first moves the affected
    axes ``overrun_deg`` beyond the pose on the approach side (other axes go
    straight to their target in that row); the measured row then comes back.

    For the paper's defaults: 22 × 16 = 352 measured rows.
    """
    if not (math.isfinite(overrun_deg) and overrun_deg > 0):
        raise ValueError(f"overrun_deg must be > 0 deg, got {overrun_deg!r}")
    a, da = _sweep(theta1_start, theta1_stop, theta1_step, "theta1")
    b, db = _sweep(theta2_start, theta2_stop, theta2_step, "theta2")
    if a.size * b.size > 4 * MAX_PLAN_POSES:  # out and back on both axes
        raise ValueError(f"theta1_step = {theta1_step:g} and theta2_step = {theta2_step:g} deg give "
                         f"{a.size * b.size // 4:,} poses, more than {MAX_PLAN_POSES:,} (use coarser steps)")
    rows, meas = [], []
    cur = last = None  # current command and last motion direction, (2,)
    for t1, e1 in zip(a, da):
        for t2, e2 in zip(b, db):
            t, e = np.array([t1, t2]), np.array([e1, e2])
            if cur is None:
                need = np.array([True, True])  # the first approach is part of the plan
            else:
                step = t - cur
                moved = np.abs(step) > MOTION_TOLERANCE_DEG
                need = np.where(moved, np.sign(step), last) != e
            if need.any():
                rows.append(np.where(need, t - e * overrun_deg, t))
                meas.append(False)
            rows.append(t)
            meas.append(True)
            cur, last = t, e
    r = np.array(rows)
    return Plan(r[:, 0], r[:, 1], np.array(meas))


@dataclass
class BidirectionalGrid:
    """Parameters of :func:`bidirectional_grid` (deg) for scenario YAML files.

    Defaults are the paper's plan (000 §4.1, Eq. (11)-(12)): θ1* −140..60
    step 20, θ2* 0..140 step 20, overrun 2 deg.
    """

    theta1_start: float = -140.0
    theta1_stop: float = 60.0
    theta1_step: float = 20.0
    theta2_start: float = 0.0
    theta2_stop: float = 140.0
    theta2_step: float = 20.0
    overrun_deg: float = 2.0

    def plan(self) -> Plan:
        """The :class:`Plan` of these parameters (000 §4.1, Eq. (11)-(12)), deg."""
        return bidirectional_grid(self.theta1_start, self.theta1_stop, self.theta1_step,
                                  self.theta2_start, self.theta2_stop, self.theta2_step,
                                  self.overrun_deg)
