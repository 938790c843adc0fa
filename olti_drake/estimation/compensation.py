"""Compensation: the joint commands that put the end effector on given targets (paper 000).

The identified model predicts the actual position of a command θ* approached
in direction ``dir`` as p = FK(θ* + Δθ(θ*, dir); L1, L2) -- Eq. (3) with the
actual angles of Eq. (7)-(9) of 000. Compensation inverts it: for a target p
find θ* with FK_model(θ*, dir) = p.

How it is solved (units: mm and degrees throughout):

* The error map acts on each joint separately (Eq. 7), so the Newton system
  J_p(θ) · diag(1 + dΔθ1/dθ1*, 1 + dΔθ2/dθ2*) · δ = p − FK_model(θ*) factors:
  the Cartesian part J_p (Eq. 3) is inverted in closed form by inverse
  kinematics with the *identified* lengths (the wanted actual angles θ), and
  the joint part is a diagonal (per-axis) Newton iteration on
  θ* + Δθ(θ*, dir) = θ, vectorized over all targets. This also holds at the
  stretched arm (θ2 = 0, inside the paper's J2 map range [0, 140]°), where the
  2x2 Cartesian Jacobian is singular and a Cartesian Newton step would not be.
  The piecewise-linear map (slope ≪ 1) converges in 1-3 iterations to
  1e-12 deg; the Cartesian residual FK_model(θ*, dir) − p is then checked to
  be ≤ 1e-9 mm.
* Directions (the approach direction is part of the command: backlash makes
  Δθ(θ*, +1) ≠ Δθ(θ*, −1)). Given per target, they are used as they are.
  Absent, they must satisfy the spec's rule on the *compensated* sequence
  itself (formats.md: +1 if the axis' last motion was positive), a fixed
  point, since the command depends on the direction and the direction on the
  step from the previous command. Per axis, both candidates θ*(+1), θ*(−1)
  are solved for every target, and one scan through the sequence picks for
  each target the direction its own step from the previous chosen command
  confirms (the previous direction first when both do). This is an exact
  fixed point, no iteration: the output satisfies
  ``approach_directions(commands) == dirs``. The one case without a fixed
  point is a reversal smaller than the backlash (the wanted step is opposite
  to the last motion but shorter than Δθ(+1) − Δθ(−1)): neither candidate is
  reached by a move in its own direction. There the reversed direction (the
  wanted motion's) is kept and the target is flagged in ``needs_approach``:
  the controller must approach it with an overrun move, as the plans do.
* Reach: targets beyond the identified arm's reach, or whose commands leave
  the identified map's grid (the map refuses extrapolation unless its policy
  is ``clamp``), raise :class:`UnreachableTargetError` with the row.

Per-axis compensation tables (:func:`compensation_table`) give, at the map
nodes, the command a controller must send per direction so that the actual
joint angle equals the wanted one -- the layout of a bidirectional pitch-error
compensation table.

Proof by simulation (:func:`compare_compensation`): the commands run through
the simulated truth robot (:class:`~olti_drake.model.scara.TrueRobot`, the numpy
twin of the Drake diagram; :func:`olti_drake.sim.compensation_check.drake_end_effector` runs the same commands
through ``ErrorMapJoint`` and the ``MultibodyPlant``).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.csvio import check_finite, check_values, read_table, write_table
from olti_drake.model.errormap import GRID_TOLERANCE_DEG, MOTION_TOLERANCE_DEG, ErrorMap
from olti_drake.model.scara import JointCommands, ScaraModel, inverse_kinematics

#: Cartesian convergence required of every compensated command, mm.
TOLERANCE_MM = 1e-9
#: Newton stops when |θ* + Δθ(θ*, dir) − θ| is below this on every target, deg.
JOINT_TOLERANCE_DEG = 1e-12
MAX_ITERATIONS = 50
#: The four (dir1, dir2) approach combinations.
DIRECTION_COMBOS = ((1, 1), (1, -1), (-1, 1), (-1, -1))


class UnreachableTargetError(ValueError):
    """A target has no compensated command (outside the reach or the map grid); ``row`` is 0-based."""

    def __init__(self, message: str, row: int):
        super().__init__(message)
        self.row = row


@dataclass(frozen=True)
class Compensation:
    """Compensated commands for N targets (inverse of Eq. 3 with Eq. 7 of 000).

    ``commands``: θ1*, θ2* (deg) and dir1, dir2 (±1); ``targets_mm`` (N, 2);
    ``residual_mm`` (N,): |FK_model(commands) − target|, mm; ``iterations``:
    Newton iterations (the most any axis and direction needed);
    ``needs_approach`` (N, 2) bool: targets whose direction the sequence alone
    cannot produce (a reversal within the backlash, see the module docstring).
    """

    commands: JointCommands
    targets_mm: np.ndarray
    residual_mm: np.ndarray
    iterations: int
    needs_approach: np.ndarray


# -- one axis: invert Eq. (7) -------------------------------------------------------------------------
def axis_maps(model: ScaraModel):
    """The (J1, J2) deviations Δθ(θ*, dir) of ``model`` as ErrorMaps holding their end values, deg.

    Error map: the model's maps (Eq. 7-9 of 000) with ``outside="clamp"``, so
    Newton iterates may step past the grid; the grid is checked at the end.
    D-H (Eq. 4): J1 none, J2 the constant offset θ20.
    """
    if model.is_errormap:
        return tuple(dataclasses.replace(m, outside="clamp") for m in (model.map1, model.map2))
    t20 = float(model.theta20_deg)
    return (ErrorMap([0.0], [0.0], [0.0], axis="J1", outside="clamp"),
            ErrorMap([0.0], [t20], [t20], axis="J2", outside="clamp"))


def deviation_slope(m: ErrorMap, theta_deg, direction) -> np.ndarray:
    """dΔθ/dθ* (deg/deg) of the interpolated map, Eq. (7)-(9) of 000: the slope of the segment holding θ*.

    Zero beyond the grid (the end value is held) and for a one-node map.
    """
    th = np.asarray(theta_deg, dtype=float).ravel()
    g = m.grid_deg
    if m.n_nodes == 1:
        return np.zeros_like(th)
    cols, _ = dataclasses.replace(m, outside="clamp").interpolation(th, direction)
    v = m.values[cols]
    i = cols[:, 0] % m.n_nodes
    inside = (th >= g[0]) & (th <= g[-1])
    return np.where(inside, (v[:, 1] - v[:, 0]) / (g[i + 1] - g[i]), 0.0)


def check_invertible(m: ErrorMap) -> None:
    """Raise unless θ* + Δθ(θ*, dir) increases with θ* (slope of Eq. 7 of 000 > −1 deg/deg) in both directions."""
    g = m.grid_deg
    if m.n_nodes < 2:
        return
    for name, v in (("forward", m.forward_deg), ("reverse", m.reverse_deg)):
        s = np.diff(v) / np.diff(g)
        if np.any(s <= -1.0):
            k = int(np.argmin(s))
            raise ValueError(f"error map {m.axis} ({name}): slope {s[k]:g} deg/deg between {g[k]:g} and "
                             f"{g[k + 1]:g} deg makes the command-to-angle map non-invertible")


def invert_axis(m: ErrorMap, theta_deg, direction, tol_deg: float = JOINT_TOLERANCE_DEG,
                max_iterations: int = MAX_ITERATIONS):
    """Commands θ* (deg) with θ* + Δθ(θ*, dir) = θ: Eq. (7) of 000 inverted by Newton, vectorized.

    Args:
        m: the axis' deviation (an ErrorMap; use ``outside="clamp"`` if iterates may leave the grid).
        theta_deg: (K,) wanted actual angles, deg.
        direction: (K,) or scalar approach directions, +1/−1.

    Starts at θ − Δθ(θ, dir); each step divides the residual by 1 + dΔθ/dθ*
    (:func:`deviation_slope`). Returns (θ* (K,) deg, iterations taken).
    """
    th = np.asarray(theta_deg, dtype=float).ravel()
    d = np.broadcast_to(np.asarray(direction, dtype=float), th.shape)
    cmd = th - m(th, d)
    for it in range(max_iterations + 1):
        r = cmd + m(cmd, d) - th
        if np.max(np.abs(r), initial=0.0) <= tol_deg:
            return cmd, it
        cmd = cmd - r / (1.0 + deviation_slope(m, cmd, d))
    raise RuntimeError(f"error map {m.axis}: Newton did not converge in {max_iterations} iterations "
                       f"(residual {np.max(np.abs(r)):g} deg)")


def _consistent(cmd: float, prev_cmd: float, prev_dir: float, d: float) -> bool:
    """Does moving from ``prev_cmd`` to ``cmd`` leave the axis in direction ``d`` (formats.md rule)?"""
    if not np.isfinite(prev_cmd) or abs(cmd - prev_cmd) <= MOTION_TOLERANCE_DEG:
        return d == prev_dir
    return np.sign(cmd - prev_cmd) == d


def sequence_directions(plus_deg, minus_deg, start_deg: float = np.nan, start_direction: float = 1.0):
    """Directions of one axis consistent with the command sequence they select (formats.md rule).

    Args:
        plus_deg, minus_deg: (K,) the compensated command of every target for
            direction +1 and −1 (:func:`invert_axis`), deg.
        start_deg: the command before the first target, deg (NaN: the first
            target is where the axis starts, it keeps ``start_direction``).
        start_direction: direction of the last motion before the sequence.

    Returns:
        dirs (K,) ±1 and needs_approach (K,) bool (a reversal within the
        backlash: no direction is confirmed by its own step; the reversed one
        is kept). With dirs chosen, command k = plus or minus by dirs[k].
    """
    prev_cmd, prev_dir = float(start_deg), float(start_direction)
    dirs = np.empty(len(plus_deg))
    flag = np.zeros(len(plus_deg), dtype=bool)
    for k, cand in enumerate(zip(plus_deg, minus_deg)):
        ok = [d for d in (prev_dir, -prev_dir) if _consistent(cand[d < 0], prev_cmd, prev_dir, d)]
        d = ok[0] if ok else -prev_dir
        flag[k] = not ok
        dirs[k], prev_cmd, prev_dir = d, cand[d < 0], d
    return dirs, flag


# -- targets -> commands ---------------------------------------------------------------------------
def wanted_angles(model: ScaraModel, x_mm, y_mm, elbow: int = 1) -> np.ndarray:
    """Actual joint angles (N, 2) deg that put the end effector at (x, y) mm: Eq. (3) of 000 inverted.

    Uses the model's (identified) L1, L2; ``elbow`` as in
    :func:`~olti_drake.model.scara.inverse_kinematics` (+1: θ2 ≥ 0). Raises
    :class:`UnreachableTargetError` for the first target beyond the reach.
    """
    x, y = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x_mm, y_mm))
    L1, L2 = model.L1_mm, model.L2_mm
    r = np.hypot(x, y)
    bad = np.flatnonzero(~((r <= L1 + L2 + 1e-9) & (r >= abs(L1 - L2) - 1e-9)))
    if bad.size:
        k = int(bad[0])
        raise UnreachableTargetError(f"target ({x[k]:g}, {y[k]:g}) mm is {r[k]:.6g} mm from the J1 axis, outside "
                                     f"the identified arm's reach [{abs(L1 - L2):.6g}, {L1 + L2:.6g}] mm", k)
    return np.column_stack(inverse_kinematics(x, y, L1, L2, elbow=elbow))


def _check_grid(model: ScaraModel, cmd: JointCommands, targets) -> None:
    """Raise for the first command outside a map grid whose policy is 'error' (no extrapolation)."""
    if not model.is_errormap:
        return
    first = None
    for m, c in ((model.map1, cmd.theta1_deg), (model.map2, cmd.theta2_deg)):
        out = np.flatnonzero((c < m.grid_deg[0] - GRID_TOLERANCE_DEG) | (c > m.grid_deg[-1] + GRID_TOLERANCE_DEG))
        if m.outside == "error" and out.size and (first is None or out[0] < first[0]):
            first = (int(out[0]), m, c[out[0]])
    if first is not None:
        k, m, c = first
        raise UnreachableTargetError(
            f"target ({targets[k, 0]:g}, {targets[k, 1]:g}) mm needs {m.axis} command {c:.6g} deg, outside the "
            f"identified map grid [{m.grid_deg[0]:g}, {m.grid_deg[-1]:g}] deg (the map does not extrapolate)", k)


def _axis_commands(m: ErrorMap, theta, given, start_deg, start_direction):
    """(commands, dirs, needs_approach, iterations) of one axis; ``given`` directions or None."""
    if given is not None:
        d = np.broadcast_to(np.asarray(given, dtype=float), theta.shape).copy()
        cmd, it = invert_axis(m, theta, d)
        return cmd, d, np.zeros(theta.shape, dtype=bool), it
    (plus, i1), (minus, i2) = invert_axis(m, theta, 1.0), invert_axis(m, theta, -1.0)
    d, flag = sequence_directions(plus, minus, start_deg, start_direction)
    return np.where(d > 0, plus, minus), d, flag, max(i1, i2)


def compensate(model: ScaraModel, x_mm, y_mm, dir1=None, dir2=None, elbow: int = 1,
               start_deg=(np.nan, np.nan), start_direction=(1.0, 1.0)) -> Compensation:
    """Commands θ* (deg) and directions with FK_model(θ*, dir) = target: Eq. (3) with Eq. (7) of 000 inverted.

    Args:
        model: identified ScaraModel (error map or D-H), e.g. from
            :func:`~olti_drake.io.result.load_result`.
        x_mm, y_mm: (N,) targets, mm, in the order the robot visits them.
        dir1, dir2: (N,) approach directions ±1 per target, or None to derive
            them from the compensated sequence itself (module docstring).
        elbow: +1 (θ2 ≥ 0) or −1, as in ``inverse_kinematics``.
        start_deg, start_direction: (J1, J2) command before the first target
            (NaN: none) and the direction of the last motion before it.

    Raises :class:`UnreachableTargetError` (with the 0-based row) for a target
    beyond the reach or needing a command outside a map grid whose policy is
    'error'. The result's residuals are ≤ :data:`TOLERANCE_MM`.
    """
    targets = np.column_stack([np.atleast_1d(np.asarray(v, dtype=float)) for v in (x_mm, y_mm)])
    theta = wanted_angles(model, targets[:, 0], targets[:, 1], elbow)
    maps = axis_maps(model)
    for m in maps:
        check_invertible(m)
    axes = [_axis_commands(m, theta[:, a], g, start_deg[a], start_direction[a])
            for a, (m, g) in enumerate(zip(maps, (dir1, dir2)))]
    cmd = JointCommands(axes[0][0], axes[1][0], axes[0][1], axes[1][1])
    _check_grid(model, cmd, targets)
    residual = np.hypot(*(model.positions(cmd) - targets).T)
    if residual.size and residual.max() > TOLERANCE_MM:
        k = int(np.argmax(residual))
        raise RuntimeError(f"compensation of target row {k} left a residual of {residual[k]:g} mm")
    return Compensation(cmd, targets, residual, max(a[3] for a in axes), np.column_stack([a[2] for a in axes]))


# -- per-axis compensation tables ------------------------------------------------------------------
def compensation_table(m: ErrorMap) -> Dict[str, np.ndarray]:
    """Bidirectional compensation table of one axis at its map nodes: Eq. (7) of 000 inverted.

    For each node angle θ (``angle_deg``: the actual joint angle wanted), the
    command a controller must send so that the actual angle is θ, per
    approach direction: ``forward_command_deg`` solves θ* + Δθ(θ*, +1) = θ,
    ``reverse_command_deg`` with −1; ``*_correction_deg`` = command − θ. All
    deg. Beyond the grid ends the map holds its end values (a table must
    cover its own end rows). Between rows a controller interpolates linearly,
    which is exact to second order (the slope of Δθ times the correction).
    """
    clamp = dataclasses.replace(m, outside="clamp")
    check_invertible(clamp)
    g = m.grid_deg
    fwd, _ = invert_axis(clamp, g, 1.0)
    rev, _ = invert_axis(clamp, g, -1.0)
    return {"angle_deg": g, "forward_correction_deg": fwd - g, "reverse_correction_deg": rev - g,
            "forward_command_deg": fwd, "reverse_command_deg": rev}


def write_tables(model: ScaraModel, out_dir, source: str = "") -> list:
    """Write ``J1_compensation.csv`` and ``J2_compensation.csv`` (:func:`compensation_table`) into ``out_dir``.

    Only error-map models have tables (Eq. 6-9 of 000). Returns the paths.
    """
    if not model.is_errormap:
        raise ValueError("compensation tables need an error-map result (model 'errormap'); a D-H model has no map")
    from olti_drake.io.outputs import make_dir

    make_dir(out_dir)
    paths = []
    for m in (model.map1, model.map2):
        path = os.path.join(out_dir, f"{m.axis}_compensation.csv")
        write_table(path, compensation_table(m), {},
                    comments=[f"olti compensate: bidirectional compensation table of {m.axis}{source}; degrees",
                              "angle_deg: wanted actual angle (map node); forward/reverse_command_deg: the "
                              "command to send when approaching in +1/-1 (000 Eq. 7 inverted)",
                              "correction = command - wanted; beyond the grid ends the map holds its end values"])
        paths.append(path)
    return paths


# -- files -----------------------------------------------------------------------------------------------
def load_targets(path):
    """Read ``targets.csv`` (formats.md: x_mm, y_mm required; dir1, dir2 optional, ±1).

    Returns (x (N,) mm, y (N,) mm, dir1 or None, dir2 or None, file lines (N,)).
    Errors are one line ``FILE:LINE: ...`` naming the column.
    """
    t = read_table(path, ("x_mm", "y_mm"), optional=("dir1", "dir2"), integer=("dir1", "dir2"))
    present = [c for c in ("x_mm", "y_mm", "dir1", "dir2") if c in t]
    check_finite(t, path, present)
    for c in ("dir1", "dir2"):
        if c in t:
            check_values(t, path, c, (-1.0, 1.0))
    return t["x_mm"], t["y_mm"], t.get("dir1"), t.get("dir2"), t["_line"]


def compensate_file(model: ScaraModel, targets_path, elbow: int = 1):
    """:func:`compensate` of a targets file -> (Compensation, file lines (N,)).

    Errors name the file and line (``FILE:LINE: ...``), e.g. an unreachable target.
    """
    x, y, d1, d2, lines = load_targets(targets_path)
    try:
        return compensate(model, x, y, d1, d2, elbow), lines
    except UnreachableTargetError as e:
        raise InputError(f"{os.fspath(targets_path)}:{lines[e.row]}: {e}") from None


def write_commands(comp: Compensation, path, comments=()) -> None:
    """Write the compensated ``commands.csv`` (formats.md) with the target x_mm, y_mm (mm, deg)."""
    c = comp.commands
    cols = {"theta1_deg": c.theta1_deg, "theta2_deg": c.theta2_deg, "dir1": c.dir1, "dir2": c.dir2,
            "x_mm": comp.targets_mm[:, 0], "y_mm": comp.targets_mm[:, 1]}
    write_table(path, cols, {"theta1_deg": "%.15g", "theta2_deg": "%.15g", "dir1": "%d", "dir2": "%d"}, comments)


# -- proof by simulation ------------------------------------------------------------------------------
def frame_rotation_deg(truth, at_deg: float = 0.0) -> float:
    """Angle (deg) of the result frame in the truth robot's base frame: (Δθ1(at, +1) + Δθ1(at, −1))/2.

    The error-map result fixes the unobservable rotation about J1 by this
    gauge (X along the arm at θ1* = ``at_deg``, mean of both directions;
    formats.md, Eq. (7) of 000), so a target given in the result's frame lies
    rotated by this angle in the truth's base frame. ``truth``: TrueRobot.
    """
    dev = truth.deviation("J1")
    return float(np.mean(dev(np.array([at_deg, at_deg]), np.array([1.0, -1.0]))))


def positioning_errors(truth, commands: JointCommands, targets_mm, rotation_deg: float = 0.0) -> np.ndarray:
    """Actual − target (N, 2) mm: the truth robot (Eq. 3 with its true Eq. 7) executing ``commands``.

    The truth's positions are rotated by −``rotation_deg`` about J1 into the
    result's frame (:func:`frame_rotation_deg`).
    """
    p = truth.end_effector(commands.theta1_deg, commands.theta2_deg, commands.dir1, commands.dir2)
    a = -np.radians(rotation_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return p @ R.T - np.asarray(targets_mm, dtype=float)


def _rms(e) -> float:
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) if len(e) else float("nan")


def error_summary(errors, commands: JointCommands) -> dict:
    """RMS and max (mm) of 2D errors (N, 2) mm, overall and per (dir1, dir2) combination (counts ``n_...``)."""
    e = np.asarray(errors, dtype=float)
    out = {"rms_mm": _rms(e), "max_mm": float(np.max(np.hypot(*e.T), initial=0.0)), "n": len(e)}
    for d1, d2 in DIRECTION_COMBOS:
        s = (commands.dir1 == d1) & (commands.dir2 == d2)
        key = f"{d1:+d}{d2:+d}"
        out[f"rms_{key}_mm"], out[f"n_{key}"] = _rms(e[s]), int(s.sum())
    return out


def register(pred, meas):
    """Rotate ``pred`` (N, 2) mm about the J1 axis (origin) onto ``meas`` (N, 2) mm, least squares.

    Closed form (2D Procrustes without translation): the angle maximizing
    Σ meas · R pred is atan2(Σ pred × meas, Σ pred · meas). Returns
    (rotated pred (N, 2) mm, angle deg): the frame's rotation about J1 is the gauge of 000 (§3.2.2), and
    the tracker registration of 000 §4.3 removes it the same way.
    """
    p, m = np.asarray(pred, dtype=float), np.asarray(meas, dtype=float)
    angle = np.arctan2(np.sum(p[:, 0] * m[:, 1] - p[:, 1] * m[:, 0]), np.sum(p * m))
    c, s = np.cos(angle), np.sin(angle)
    return p @ np.array([[c, s], [-s, c]]), float(np.degrees(angle))


def compare_compensation(models: Dict[str, ScaraModel], truth, targets_mm, dir1=None, dir2=None,
                         rotation_deg: Optional[float] = None, elbow: int = 1) -> dict:
    """Positioning errors of the truth robot executing each model's compensated commands (000 §4.3 paths).

    ``models``: name -> ScaraModel; a nominal D-H model (nominal L1, L2,
    θ20 = 0) gives the commands of an uncompensated controller (plain
    inverse kinematics), the "before". ``targets_mm`` (N, 2), ``dir1``/``dir2``
    as in :func:`compensate`. ``rotation_deg``: the result frame in the truth
    frame (default :func:`frame_rotation_deg`). Returns name -> dict of
    :func:`error_summary` plus "errors" (N, 2) mm, "compensation", and the
    same errors after a best-fit rotation about J1 per model and target set
    (:func:`register`, as the validation of 000 §4.3 does):
    "rms_registered_mm", "max_registered_mm", "registration_deg".
    """
    t = np.asarray(targets_mm, dtype=float)
    rot = frame_rotation_deg(truth) if rotation_deg is None else rotation_deg
    out = {}
    for name, model in models.items():
        comp = compensate(model, t[:, 0], t[:, 1], dir1, dir2, elbow)
        e = positioning_errors(truth, comp.commands, t, rot)
        registered, angle = register(e + t, t)  # the actual positions, best-fit rotated onto the targets
        er = registered - t
        out[name] = {**error_summary(e, comp.commands), "errors": e, "compensation": comp,
                     "rms_registered_mm": _rms(er), "max_registered_mm": float(np.max(np.hypot(*er.T), initial=0.0)),
                     "registration_deg": angle}
    return out
