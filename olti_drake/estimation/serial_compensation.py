"""Compensation of an N-joint serial robot: joint commands that put the tool point on wanted points by the
identified model (000 Eq. (3) in 3D with Eq. (7) inverted), keeping the programmed tool orientation.

For every target t (mm, root frame) with its nominal pose θ_nom (the program's own command, deg) and
approach directions (kept unchanged), Newton iterations on the commands θ* solve, by task priority
(damped least squares, SVD with a relative cut :data:`RCOND`):

1. the tool point on the target: p(θ*, dir) = t (3 equations; the identified model, maps included);
2. in the null space of (1), the tool orientation of the nominal pose: the tips of the tool frame's axes,
   :data:`ORIENTATION_ARM_MM` long, relative to the tool point, where the identified model puts them at
   θ_nom — the program's orientation as it executes. Position readings cannot see the tool orientation
   (its three parameters are not in any base set), so turning it toward another "programmed" one would
   rest on unidentified parameters and cost large joint motions near a wrist singularity;
3. in what is left (a redundant arm, e.g. 7 joints), the commands nearest θ_nom, weighed
   :data:`NEARNESS_MM_PER_DEG` — the nominal pose's null-space choice.

The Jacobian is the model's ∂p/∂θ at the actual angles (the map's slope, ~1e-3, is left out: it only
slows the convergence, whose test is the residual itself). A target is refused (one line naming its file
line) when the residual stays above :data:`TOLERANCE_MM` (out of reach, or off the surface a robot with
fewer than 3 effective joints can reach), when a command leaves the model's joint limits, or leaves a
map's grid (``outside="error"``). Units: mm and degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.errormap import OutsideGridError

#: A compensated tool point must be on its target by the model to this, mm.
TOLERANCE_MM = 1e-6
#: Newton iterations at most.
MAX_ITERATIONS = 50
#: Length of the tool-frame axes whose tips carry the orientation, mm (1 mm of tip = 0.57 deg).
ORIENTATION_ARM_MM = 100.0
#: Weight of "stay near the nominal pose" against the orientation tips, mm per deg.
NEARNESS_MM_PER_DEG = 1e-3
#: Singular values below this fraction of the largest are not inverted (rank of the tasks).
RCOND = 1e-9
#: Largest joint step of one Newton iteration, deg (a far target is approached, not jumped at).
MAX_STEP_DEG = 10.0


@dataclass(frozen=True)
class SerialCompensation:
    """Compensated commands (M, N) deg with the targets' directions (M, N) or None, the residual
    |p_model(commands) − target| (M,) mm, the tool orientation change from the nominal pose's (M,) deg
    (largest axis-tip angle), the correction command − nominal (M, N) deg, the Newton iterations."""

    commands: np.ndarray
    dirs: object
    residual_mm: np.ndarray
    orientation_change_deg: np.ndarray
    correction_deg: np.ndarray
    iterations: int


def _tool_index(model) -> int:
    return model.names.index("tool_x_mm")


def frame_points(model, commands, dirs, x=None, jacobian=True):
    """The tool point and the tips of the tool frame's axes (M, 4, 3) mm, and their ∂/∂θ (M, 4, 3, N) mm/deg."""
    x = model.start_vector() if x is None else np.asarray(x, float)
    k = _tool_index(model)
    pts, jacs = [], []
    for offset in np.vstack([np.zeros(3), ORIENTATION_ARM_MM * np.eye(3)]):
        xi = x.copy()
        xi[k:k + 3] += offset
        if jacobian:
            p, jp = model.jacobian(commands, dirs, xi)
            jacs.append(jp.angle)
        else:
            p = model.positions(commands, dirs, xi)
        pts.append(p)
    return np.stack(pts, axis=1), (np.stack(jacs, axis=1) if jacobian else None)


def _step(jp, ep, jo, eo, dq_nom):
    """One task-priority step for one target: position, then orientation, then nearness (deg)."""
    u, s, vt = np.linalg.svd(jp, full_matrices=True)
    rank = int(np.sum(s > RCOND * max(s.max(), 1e-300)))
    d1 = vt[:rank].T @ ((u[:, :rank].T @ ep) / s[:rank])
    null = vt[rank:].T
    if null.shape[1] == 0:
        return d1
    a = np.vstack([jo @ null, NEARNESS_MM_PER_DEG * null])
    b = np.concatenate([eo - jo @ d1, NEARNESS_MM_PER_DEG * (dq_nom - d1)])
    z = np.linalg.lstsq(a, b, rcond=RCOND)[0]
    return d1 + null @ z


def compensate_serial(model, targets_mm, nominal_deg, dirs=None, lines=None, source: str = "targets"):
    """Commands putting the tool point on ``targets_mm`` (M, 3) mm by ``model`` (module docstring)."""
    targets = np.atleast_2d(np.asarray(targets_mm, float))
    nominal = np.atleast_2d(np.asarray(nominal_deg, float))
    lines = np.arange(1, len(targets) + 1) if lines is None else np.asarray(lines)
    chain = model.chain
    start, _ = _evaluate(model, nominal, dirs, lines, source, jacobian=False)
    want = start[:, 1:] - start[:, :1]
    q = nominal.copy()
    iterations = 0
    for iterations in range(1, MAX_ITERATIONS + 1):
        pts, jac = _evaluate(model, q, dirs, lines, source)
        ep = targets - pts[:, 0]
        eo = (want - (pts[:, 1:] - pts[:, :1])).reshape(len(q), 9)
        jo = (jac[:, 1:] - jac[:, :1]).reshape(len(q), 9, -1)
        delta = np.array([_step(jac[i, 0], ep[i], jo[i], eo[i], nominal[i] - q[i]) for i in range(len(q))])
        big = np.abs(delta).max(axis=1, keepdims=True)
        delta *= np.minimum(1.0, MAX_STEP_DEG / np.maximum(big, 1e-300))
        q = _backtrack(model, q, delta, dirs, targets, np.linalg.norm(ep, axis=1), lines, source)
        if np.abs(delta).max() < 1e-11 and np.linalg.norm(ep, axis=1).max() < TOLERANCE_MM:
            break
    pts, _ = _evaluate(model, q, dirs, lines, source, jacobian=False)
    residual = np.linalg.norm(pts[:, 0] - targets, axis=1)
    bad = np.flatnonzero(residual > TOLERANCE_MM)
    if bad.size:
        i = bad[0]
        raise InputError(f"{source}:{lines[i]}: target ({', '.join(f'{v:.6g}' for v in targets[i])}) mm cannot be "
                         f"reached by the model: {residual[i]:.3g} mm off after {iterations} Newton iterations (out "
                         f"of reach, or off the surface the robot's joints can reach); {bad.size} such target(s)")
    _check_limits(chain, q, lines, source)
    tips = pts[:, 1:] - pts[:, :1]
    turn = np.degrees(np.arcsin(np.clip(np.linalg.norm(tips - want, axis=2).max(axis=1) / ORIENTATION_ARM_MM, 0, 1)))
    return SerialCompensation(q, dirs, residual, turn, q - nominal, iterations)


def _backtrack(model, q, delta, dirs, targets, before, lines, source, halvings: int = 12):
    """q + delta, the step halved per target while it moves the tool point away from its target (Newton
    near a singular pose, e.g. a stretched elbow, overshoots)."""
    step = np.ones((len(q), 1))
    for _ in range(halvings):
        trial = q + step * delta
        after = np.linalg.norm(_evaluate(model, trial, dirs, lines, source, jacobian=False)[0][:, 0] - targets, axis=1)
        worse = after > before + TOLERANCE_MM
        if not worse.any():
            break
        step[worse] *= 0.5
    return q + step * delta


def _evaluate(model, q, dirs, lines, source, jacobian=True):
    try:
        return frame_points(model, q, dirs, jacobian=jacobian)
    except OutsideGridError as e:
        raise InputError(f"{source}:{lines[e.row]}: the compensated command leaves the identified map: {e} "
                         f"(or run with --outside clamp)") from None


def _check_limits(chain, q, lines, source) -> None:
    """Refuse a command beyond the model's joint limits, naming the target's line and the joint."""
    low, high = q < chain.lower_deg - 1e-9, q > chain.upper_deg + 1e-9
    bad = np.argwhere(low | high)
    if bad.size:
        i, j = bad[0]
        limit = chain.lower_deg[j] if low[i, j] else chain.upper_deg[j]
        raise InputError(f"{source}:{lines[i]}: the compensated command of {chain.joint_names[j]} is "
                         f"{q[i, j]:.6g} deg, beyond its limit {limit:g} deg in {chain.path}")
