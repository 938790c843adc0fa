"""Five-axis compensation (issue 25, item 6): the commands X, Y, Z and rotary axes that put a tool point on wanted
points *with* wanted tool directions in the workpiece frame (five-axis TCP), by an identified
:class:`~olti_drake.model.five_axis_errors.FiveAxisPositionModel`; and the ISO 10791-6 BK-type check of it on a
truth machine (:func:`bk_check`).

The inverse runs twice, one Gauss-Newton each (:func:`_gauss_newton`, vectorized over the targets):

1. **nominal** (the machine file, no errors): from the rotary poses of a 5° grid nearest in tool direction (and
   the reference pose), with the linear axes put on the point (:func:`~olti_drake.model.five_axis_plan.
   linear_for_points`); of the converged solutions within travel, the one whose rotary commands are nearest the
   reference (the targets' ``<letter>_cmd_deg`` when given, else 0) -- one rule per row, so the row order does
   not matter;
2. **identified**: from the nominal solution, on the error model's tool pose and its analytic command Jacobian
   (:meth:`~olti_drake.model.five_axis_errors.FiveAxisPositionModel.command_jacobian`). The tool point is solved
   exactly; the tool direction too, but for a tie of weight µ² = 10⁻⁶ (:data:`ANCHOR`) to the nominal rotary
   commands: negligible away from the singular direction (the tool along a rotary axis line, where the exact
   direction could need that axis to turn far), bounded there; :attr:`Compensation.direction_residual_rad`
   says what is left.

Residuals are in mm and in rad × :data:`LEVER_MM` (a tool direction error of 1 µrad counts as 0.1 µm), the rotary
unknowns likewise in rad × LEVER_MM. Commands leaving the travel are refused naming the row; a row not converged
(or a direction no rotary pose reaches) too. Units: mm and degrees (commands), unit vectors (directions).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.errormap import approach_directions
from olti_drake.model.five_axis import DEG, ROTARY, FiveAxisMachine
from olti_drake.model.five_axis_errors import FiveAxisErrors, FiveAxisPositionModel
from olti_drake.model.five_axis_plan import _tool_points, linear_for_points

#: The lever (mm) at which a tool direction error (rad) counts as a tool point error.
LEVER_MM = 100.0
#: The tie of the identified inverse's rotary commands to the nominal ones (rad × LEVER_MM per the same).
ANCHOR = 1e-3
#: The nominal start grid (deg) of the rotary axes and the number of distinct starts taken from it.
START_GRID_DEG, STARTS = 5.0, 3
#: Converged: every unknown's last step below this (mm, or rad × LEVER_MM).
STEP_TOL = 1e-10
#: Largest rotary step of one iteration (deg): keeps Newton on its branch.
MAX_ROTARY_STEP_DEG = 20.0
#: The pole of a rotary axis: where turning it turns the tool direction by less than this (rad per rad; sin 0.5 deg:
#: C with A within 0.5 deg of 0), the axis is held at its nominal command with weight POLE_ANCHOR, as a controller
#: does at its pole. Anchored by ANCHOR alone, a direction error no nearby pose removes (the tilt the error motions
#: give the tool there) pulls the axis along a flat valley towards the far pose that removes it, by 1e-6 to 1e-3 of
#: the cost a step, the steps halved 5-10 times: no convergence in 60 steps (measured on BK paths at A = 0). The
#: tool point is met either way; the direction's residual is reported.
POLE_SENSITIVITY, POLE_ANCHOR = np.sin(np.radians(0.5)), 1.0
#: A row whose point is met and whose cost a step lowers by less than this fraction has converged.
COST_TOL = 1e-9
#: The most halvings of a Gauss-Newton step that does not lower a row's cost (:func:`_gauss_newton`).
HALVINGS = 30
#: A compensated command reaches its tool point within this (mm).
POINT_TOL_MM = 1e-6
#: A nominal solution reaches the wanted direction within this (rad) and the point within this (mm).
NOMINAL_TOL_RAD, NOMINAL_TOL_MM = 1e-9, 1e-9


@dataclass
class Compensation:
    """Compensated commands (M, n_axes; mm, deg; columns ``machine.axes``), the approach directions used (M,
    n_rotary) or None, the nominal inverse's commands, the wanted points (M, 3) mm and directions (M, 3), and per
    row the identified model's residuals: |point| mm and the angle of the tool direction rad."""

    commands: np.ndarray
    directions: Optional[np.ndarray]
    nominal: np.ndarray
    points_mm: np.ndarray
    tool_dirs: np.ndarray
    position_residual_mm: np.ndarray
    direction_residual_rad: np.ndarray
    iterations: int


def sequence_directions(rotary_deg) -> np.ndarray:
    """(M, n_rotary) ±1: formats.md's rule over the commands in their order, the first approach positive."""
    return approach_directions(rotary_deg, np.asarray(rotary_deg)[0] - 1.0)


def _where(what: str, i: int, lines) -> str:
    """Row i of ``what``: 'what: row i', or 'what:LINE' by its file line."""
    return f"{what}: row {i}" if lines is None else f"{what}:{int(lines[i])}"


def _unit_rows(v, what: str, lines) -> np.ndarray:
    """(M, 3) unit vectors of ``v``; a row not finite or of length 0 refused naming it."""
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=1)
    bad = np.flatnonzero(~np.isfinite(n) | (n < 1e-9))
    if bad.size:
        raise InputError(f"{_where(what, bad[0], lines)}: tool direction {v[bad[0]].tolist()} has no length")
    return v / n[:, None]


def nominal_directions(machine: FiveAxisMachine, rotary_deg) -> np.ndarray:
    """(M, 3) the nominal tool direction (the tool frame's z axis) in the workpiece frame at rotary commands (M,
    n_rotary) deg (the linear axes turn nothing)."""
    rot = np.atleast_2d(np.asarray(rotary_deg, float))
    cmd = np.zeros((len(rot), len(machine.axes)))
    cmd[:, [machine.axes.index(a) for a in machine.rotary]] = rot
    z = _tool_points(machine, cmd, (0.0, 0.0, 1.0)) - _tool_points(machine, cmd, (0.0, 0.0, 0.0))
    return z


def _full_turns(machine: FiveAxisMachine) -> np.ndarray:
    """(n_axes,) True for a rotary axis whose travel is a full turn (−180..180: −180 and 180 are one angle)."""
    span = machine.upper - machine.lower
    return np.isin(list(machine.axes), list(ROTARY)) & np.isfinite(span) & (span >= 360.0 - 1e-9)


def _into_travel(machine: FiveAxisMachine, c: np.ndarray) -> np.ndarray:
    """Commands with a full-turn rotary axis wrapped into its travel, then clipped into every travel."""
    c = np.where(_full_turns(machine), machine.lower + np.mod(c - machine.lower, 360.0), c)
    return np.clip(c, machine.lower, machine.upper)


def _rotary_offset(machine: FiveAxisMachine, to_deg, from_deg) -> np.ndarray:
    """to − from (deg) per rotary axis, the shorter way round on a full-turn axis: a command wrapped across its
    end (−180.1 → 179.9) is 0.2 deg from −180, not 359.8."""
    d = np.asarray(to_deg, float) - np.asarray(from_deg, float)
    turn = _full_turns(machine)[[machine.axes.index(a) for a in machine.rotary]]
    return np.where(turn, np.mod(d + 180.0, 360.0) - 180.0, d)


def _gauss_newton(machine, pose, c, points, dirs, anchor=None, max_iter: int = 60):
    """Gauss-Newton on the tool pose ``pose(commands) -> (p, d, Jp, Jd)`` for (M, n_axes) starts ``c``: point
    residual (mm), direction residual (× LEVER_MM), and, when ``anchor`` (M, n_rotary) deg is given, the rotary
    commands tied to it with weight ANCHOR, POLE_ANCHOR for an axis at its pole at the start (else each step is
    damped by ANCHOR: Levenberg–Marquardt, the exact solution). Iterates kept in the travel; a step that does not lower a row's cost is halved (up to
    :data:`HALVINGS` times): a minimum on a kink of the model (a map node, the end of a full turn) is overshot
    both ways by the full step; each step is followed by a Newton step of the linear axes on the point alone.
    Converged: no halved step lowers the cost, the step is below STEP_TOL, or the point is met and the cost fell by
    less than COST_TOL of itself. Returns (commands, converged (M,), iterations)."""
    rot = np.array([machine.axes.index(a) for a in machine.rotary], int)
    lin = np.array([machine.axes.index(a) for a in machine.linear], int)
    scale = np.ones(len(machine.axes))
    scale[rot] = DEG * LEVER_MM  # (mm-like unknowns)
    done = np.zeros(len(c), bool)
    p, d, Jp, Jd = pose(c)
    w = np.full((len(c), len(rot)), ANCHOR)
    if anchor is not None:  # (an axis at its pole is held: the tool turns about it, by < POLE_SENSITIVITY rad/rad)
        w[np.linalg.norm(Jd[:, :, rot], axis=1) / DEG < POLE_SENSITIVITY] = POLE_ANCHOR
    damp = np.zeros((len(c), len(machine.axes), len(machine.axes)))
    damp[:, rot, rot] = w ** 2

    def cost(c, p, d):
        out = np.sum((points - p) ** 2, axis=1) + LEVER_MM ** 2 * np.sum((dirs - d) ** 2, axis=1)
        if anchor is not None:
            out = out + np.sum((w * _rotary_offset(machine, anchor, c[:, rot]) * DEG * LEVER_MM) ** 2, axis=1)
        return out

    for it in range(1, max_iter + 1):
        J = np.concatenate([Jp, LEVER_MM * Jd], axis=1) / scale  # (M, 6, n_axes)
        r = np.concatenate([points - p, LEVER_MM * (dirs - d)], axis=1)
        g = np.einsum("mki,mk->mi", J, r)
        if anchor is not None:
            g[:, rot] += w ** 2 * _rotary_offset(machine, anchor, c[:, rot]) * DEG * LEVER_MM
        step = np.linalg.solve(np.einsum("mki,mkj->mij", J, J) + damp, g[..., None])[..., 0] / scale
        step[:, rot] = np.clip(step[:, rot], -MAX_ROTARY_STEP_DEG, MAX_ROTARY_STEP_DEG)
        step[done] = 0.0  # (a converged row stays where it converged)
        before, t = cost(c, p, d), np.ones(len(c))
        for _ in range(HALVINGS + 1):
            trial = _into_travel(machine, c + t[:, None] * step)
            pt, dt, Jpt, Jdt = pose(trial)
            worse = cost(trial, pt, dt) > before * (1.0 + 1e-12) + 1e-24
            if not worse.any() or _ == HALVINGS:
                break
            t = np.where(worse, 0.5 * t, t)
        # (a row no halved step lowers is at its minimum: kept, converged)
        keep = worse[:, None]
        c, p, Jp = np.where(keep, c, trial), np.where(keep, p, pt), np.where(keep[..., None], Jp, Jpt)
        # Then the point by the linear axes alone (the rotary ones held): where a rotary command lies in a flat
        # valley on a kink of the maps -- C at a singular pose, across +-180 -- the halved steps zigzag over it,
        # the point's part of every step halved with them.
        c[:, lin] += np.where(done[:, None], 0.0, np.linalg.solve(Jp[:, :, lin], (points - p)[..., None])[..., 0])
        c = _into_travel(machine, c)
        p, d, Jp, Jd = pose(c)
        after = cost(c, p, d)
        done |= worse | (np.max(np.abs(t[:, None] * step) * scale, axis=1) < STEP_TOL) | \
            ((before - after <= COST_TOL * before) & (np.linalg.norm(points - p, axis=1) < POINT_TOL_MM))
        if done.all():
            break
    return c, done, it


def _angle(a, b) -> np.ndarray:
    """(M,) angles (rad) between unit rows."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))


def _grid_starts(machine: FiveAxisMachine, dirs, reference) -> np.ndarray:
    """(M, 1 + STARTS, n_rotary) deg: the reference pose, then the grid poses nearest in tool direction, each
    at least 4 grid steps from the ones taken before (distinct branches: (A, C) and (−A, C + 180°) ...)."""
    grids = [np.arange(max(lo, -180.0), min(hi, 180.0) + 1e-9, START_GRID_DEG)
             for lo, hi in zip(*(b[[machine.axes.index(a) for a in machine.rotary]]
                                 for b in (machine.lower, machine.upper)))]
    cand = np.stack(np.meshgrid(*grids, indexing="ij"), axis=-1).reshape(-1, len(grids))
    score = dirs @ nominal_directions(machine, cand).T  # (M, G) cosines
    out = [reference]
    for _ in range(STARTS):
        best = np.argmax(score, axis=1)
        out.append(cand[best])
        near = np.max(np.abs(cand[None] - cand[best][:, None]), axis=2) < 4 * START_GRID_DEG
        score = np.where(near, -np.inf, score)
    return np.stack(out, axis=1)


def nominal_inverse(machine: FiveAxisMachine, points_mm, tool_dirs, offsets_mm, reference_deg, lines=None,
                    what: str = "targets") -> np.ndarray:
    """(M, n_axes) nominal commands putting tool points ``offsets_mm`` (M, 3; tool frame) on ``points_mm`` (M, 3)
    with the tool directions ``tool_dirs`` (M, 3, unit) in the workpiece frame: of the converged solutions from
    :func:`_grid_starts` within travel, the one nearest ``reference_deg`` (M, n_rotary) in its rotary commands.
    A row with none refused in one line naming it."""
    M, n_rot = len(points_mm), len(machine.rotary)
    starts = _grid_starts(machine, tool_dirs, reference_deg)  # (M, S, n_rot)
    S = starts.shape[1]
    pts, dirs, offs = (np.repeat(a, S, axis=0) for a in (points_mm, tool_dirs, offsets_mm))
    c0 = _linear_rows(machine, starts.reshape(-1, n_rot), pts, offs)
    em = FiveAxisErrors(machine, location=False, motions=False, tool_offsets_mm=np.unique(offs, axis=0))
    tool = _tool_index(em.tools, offs)

    def pose(c):
        return FiveAxisPositionModel(machine, em, c, None, tool).command_jacobian(np.zeros(0))

    c, _, _ = _gauss_newton(machine, pose, _into_travel(machine, c0), pts, dirs)
    p, d, _, _ = pose(c)
    ok = (np.linalg.norm(p - pts, axis=1) < NOMINAL_TOL_MM) & (_angle(d, dirs) < NOMINAL_TOL_RAD)
    rot = [machine.axes.index(a) for a in machine.rotary]
    dist = np.where(ok, np.abs(_rotary_offset(machine, c[:, rot], np.repeat(reference_deg, S, axis=0))).sum(axis=1),
                    np.inf).reshape(M, S)
    bad = np.flatnonzero(~np.isfinite(dist.min(axis=1)))
    if bad.size:
        i = bad[0]
        raise InputError(f"{_where(what, i, lines)}: no commands within the travel put the tool point on "
                         f"{np.round(points_mm[i], 6).tolist()} mm with the tool direction "
                         f"{np.round(tool_dirs[i], 6).tolist()} ({machine.path}; travel "
                         + ", ".join(f"{a} [{lo:g}, {hi:g}]" for a, lo, hi in zip(machine.axes, machine.lower,
                                                                                 machine.upper)) + ")")
    return c.reshape(M, S, -1)[np.arange(M), np.argmin(dist, axis=1)]


def _linear_rows(machine, rot, pts, offs) -> np.ndarray:
    """:func:`linear_for_points` per distinct tool offset (it takes one offset)."""
    out = np.zeros((len(rot), len(machine.axes)))
    for o in np.unique(offs, axis=0):
        sel = np.all(offs == o, axis=1)
        out[sel] = linear_for_points(machine, rot[sel], pts[sel], o)
    return out


def _tool_index(tools, offsets) -> np.ndarray:
    return np.array([int(np.flatnonzero(np.all(tools == o, axis=1))[0]) for o in offsets], int)


def compensate(model, x, machine: FiveAxisMachine, points_mm, tool_dirs=None, rotary_deg=None, tool=None,
               approach=None, lines=None, what: str = "targets") -> Compensation:
    """Commands that put the tool point of tool ``tool`` (M,) on ``points_mm`` (M, 3) mm with the tool directions
    ``tool_dirs`` (M, 3; the tool frame's z axis, normalized here) in the workpiece frame by the identified model.

    ``model(commands, directions, tool)`` -> :class:`FiveAxisPositionModel` of the identified errors (e.g.
    :meth:`olti_drake.io.five_axis_io.Machine5Result.position_model`) and ``x`` its values. ``rotary_deg`` (M,
    n_rotary): the nominal pose; without ``tool_dirs`` the wanted direction is its nominal one (the pose keeps its
    orientation), with them it picks the branch (nearest solution; default 0). ``approach`` (M, n_rotary) ±1:
    the approach directions of a bidirectional model; None: formats.md's rule over the compensated sequence
    itself (taken again until it holds). Raises InputError (one line naming the row, ``lines``: file lines) for a
    direction no pose within travel reaches, a compensated command outside the travel, a row not converged."""
    pts = np.atleast_2d(np.asarray(points_mm, float))
    M = len(pts)
    if tool_dirs is None and rotary_deg is None:
        raise InputError(f"{what}: give the tool directions or the nominal rotary commands of every row")
    rot = [machine.axes.index(a) for a in machine.rotary]
    reference = (np.zeros((M, len(rot))).clip(machine.lower[rot], machine.upper[rot]) if rotary_deg is None else
                 np.asarray(rotary_deg, float).reshape(M, len(rot)))
    lo, hi = machine.lower[rot], machine.upper[rot]
    bad = np.argwhere(~np.isfinite(reference) | (reference < lo - 1e-9) | (reference > hi + 1e-9))
    if bad.size:
        i, j = bad[0]
        raise InputError(f"{_where(what, i, lines)}: {machine.rotary[j]} = {reference[i, j]:g} deg is outside its "
                         f"travel [{lo[j]:g}, {hi[j]:g}] deg ({machine.path})")
    dirs = nominal_directions(machine, reference) if tool_dirs is None else _unit_rows(tool_dirs, what, lines)
    em = model(np.zeros((1, len(machine.axes))).clip(machine.lower, machine.upper), np.ones((1, len(rot))),
               None).errors
    tool = np.zeros(M, int) if tool is None else np.asarray(tool, int).reshape(M)
    bad = np.flatnonzero((tool < 0) | (tool >= len(em.tools)))
    if bad.size:
        raise InputError(f"{_where(what, bad[0], lines)}: tool {tool[bad[0]]} is not a tool of the model "
                         f"(0..{len(em.tools) - 1})")
    nominal = nominal_inverse(machine, pts, dirs, em.tools[tool], reference, lines, what)
    bidirectional = bool(em.maps) and em.bidirectional
    sequence = approach is None and bidirectional
    app = sequence_directions(nominal[:, rot]) if sequence else approach
    for attempt in range(4):  # (the sequence rule: directions of the compensated commands, taken again)
        def pose(cc, app=app):
            return model(cc, app, tool).command_jacobian(x)
        c, done, iterations = _gauss_newton(machine, pose, nominal, pts, dirs, anchor=nominal[:, rot])
        if not sequence or attempt == 3 or np.array_equal(sequence_directions(c[:, rot]), app):
            break  # (the directions returned are those the commands were solved with)
        app = sequence_directions(c[:, rot])
    p, d, _, _ = pose(c)
    err_p, err_d = np.linalg.norm(p - pts, axis=1), _angle(d, dirs)
    _check_solution(machine, c, done, err_p, lines, what)
    return Compensation(c, app, nominal, pts, dirs, err_p, err_d, iterations)


def _check_solution(machine, c, done, err_p, lines, what) -> None:
    """Refuse (one line, the first row) a command at the end of its travel that the point still pulls beyond
    it, or a row not converged."""
    at_end = (np.isclose(c, machine.lower, atol=1e-9) | np.isclose(c, machine.upper, atol=1e-9)) & \
        np.isfinite(machine.lower) & ~_full_turns(machine)  # (a full turn has no end)
    bad = np.flatnonzero(~done | (err_p > POINT_TOL_MM))
    if bad.size:
        i = bad[0]
        ends = [a for a, e in zip(machine.axes, at_end[i]) if e]
        why = (f"the compensated command {ends[0]} is at the end of its travel "
               f"[{machine.lower[machine.axes.index(ends[0])]:g}, {machine.upper[machine.axes.index(ends[0])]:g}]"
               f" ({machine.path}): the target is outside the travel" if ends else
               f"did not converge (tool point residual {err_p[i]:.3g} mm)")
        raise InputError(f"{_where(what, i, lines)}: {why}")


# ------------------------------------------------------------------------------------------- the BK check
@dataclass
class BKCheck:
    """Per BK-type path (:func:`~olti_drake.model.five_axis_plan.bk_paths`): its name and the true tool point's
    deviation from the ball (its mean over the path removed: the ball's set-up, unknown as an R-test nest's
    zero), max and RMS, µm, commanded nominally and compensated; the worst ratio over the paths."""

    names: tuple
    nominal_max_um: np.ndarray
    nominal_rms_um: np.ndarray
    compensated_max_um: np.ndarray
    compensated_rms_um: np.ndarray

    @property
    def ratio(self) -> float:
        """The smallest nominal / compensated max deviation over the paths."""
        return float(np.min(self.nominal_max_um / self.compensated_max_um))

    def describe(self) -> str:
        return "\n".join(f"{n}: nominal max {a:.2f} um RMS {b:.2f} um -> compensated max {c:.2f} um RMS {d:.2f} um"
                         for n, a, b, c, d in zip(self.names, self.nominal_max_um, self.nominal_rms_um,
                                                  self.compensated_max_um, self.compensated_rms_um))


def _deviations(truth, plan, commands, rot, directions=None) -> tuple:
    """(max, RMS) µm per path of the true tool point's deviation from its ball, the path's mean removed; the
    approach ``directions`` (M, n_rotary) ±1, default formats.md's rule over the commands' own sequence."""
    directions = sequence_directions(commands[:, rot]) if directions is None else directions
    e = truth.truth_positions(commands, directions, plan.tool) - plan.nests_mm[plan.nest]
    out = []
    for k in range(len(plan.nests_mm)):
        n = np.linalg.norm(e[plan.nest == k], axis=1)
        out.append((1e3 * n.max(), 1e3 * np.sqrt(np.mean(n ** 2))))
    return tuple(np.array(v) for v in zip(*out))


def bk_check(truth, plan, model, x) -> BKCheck:
    """The truth machine (:class:`~olti_drake.model.five_axis_truth.FiveAxisTruth`) on the BK-type ``plan``
    commanded (a) nominally (the plan's commands) and (b) compensated by the identified ``model``/``x``
    (:func:`compensate`: the plan's balls as the points, its rotary poses as the nominal poses); each run with
    the approach directions it is to be executed with: the nominal run those of its own sequence (formats.md's
    rule), the compensated run those the compensation was solved with and writes beside its commands (formats.md:
    commands that, executed with those directions, hit the targets). A held axis that the compensation moves
    back and forth by millidegrees would otherwise flip between its backlash branches on every row, which a
    reversal smaller than the lost motion does not do on a machine."""
    m = truth.machine
    rot = [m.axes.index(a) for a in m.rotary]
    comp = compensate(model, x, m, plan.nests_mm[plan.nest], rotary_deg=plan.commands[:, rot], tool=plan.tool,
                      what="BK paths")
    nominal = _deviations(truth, plan, plan.commands, rot)
    compensated = _deviations(truth, plan, comp.commands, rot, comp.directions)
    names = tuple(getattr(plan, "path_names", ()) or (f"path {k}" for k in range(len(plan.nests_mm))))
    return BKCheck(names, *nominal, *compensated)


__all__ = ["BKCheck", "Compensation", "bk_check", "compensate", "nominal_directions", "nominal_inverse"]
