"""Measurement plans of a five-axis machine (issue 25, item 4): open-loop tracking-interferometer programs and
ISO 10791-6 K4-like R-test paths, seeded, for any machine read by :class:`~olti_drake.model.five_axis.FiveAxisMachine`.

* :func:`tracking_plan` -- the program an open-loop tracking interferometer (paper 001, Eq. (1) with the rotary
  axes) reads: nominal tool points drawn in a box of the workpiece frame, the rotary angles swept forward then back
  (so every rotary axis is approached from both directions: formats.md's rule, the sign of its last motion), the
  linear axes solved so the nominal tool point is on the drawn point. The program is run once per station set-up
  and tool; a station is fixed on the bed (``station_frame`` ``base``) or rides on the table (``workpiece``).
* :func:`rtest_plan` -- per nest (a sphere on the table, workpiece frame), the rotary axes moved simultaneously
  from one end of their range to the other and back (K4-like), the linear axes following so the nominal tool
  point (the spindle ball) stays on the nest.
* :func:`combine` -- plans in execution order, the approach directions taken over the whole sequence.

Units: mm (linear axes, points), deg (rotary axes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Sequence, Tuple

import numpy as np

from olti_drake.errors import InputError
from olti_drake.limits import check_allocation
from olti_drake.model.errormap import approach_directions
from olti_drake.model.five_axis import FiveAxisMachine

#: Draws per wanted pose before a plan gives up finding commands within travel.
MAX_DRAWS = 50
#: The frames a station may stand in (formats.md ``station_frame``).
STATION_FRAMES = ("base", "workpiece")


@dataclass
class FiveAxisPlan:
    """Rows in execution order. ``axes``: the command columns (X, Y, Z, A, C ...); ``commands`` (K, n_axes) mm/deg;
    ``directions`` (K, n_axes) ±1 (formats.md's rule over the whole sequence); ``tool`` (K,); ``station`` (K,) the
    interferometer station of a distance row, −1 on R-test rows; ``nest`` (K,) the nest of an R-test row, −1 on
    distance rows; ``station_frames``: per station 'base' or 'workpiece'; ``nests_mm`` (N_n, 3) workpiece frame."""

    axes: Tuple[str, ...]
    commands: np.ndarray
    directions: np.ndarray
    tool: np.ndarray
    station: np.ndarray
    nest: np.ndarray
    station_frames: Tuple[str, ...] = ()
    nests_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    path_names: Tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.commands)

    def rotary_directions(self, machine: FiveAxisMachine) -> np.ndarray:
        """(K, n_rotary) the rotary axes' directions, as :meth:`FiveAxisTruth.truth_positions` takes them."""
        return self.directions[:, [self.axes.index(a) for a in machine.rotary]]

    @property
    def is_distance(self) -> np.ndarray:
        return self.station >= 0


def linear_for_points(machine: FiveAxisMachine, rotary_deg, points_mm, offset_mm=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(M, n_axes) commands whose nominal tool point ``offset_mm`` (tool frame) is at ``points_mm`` (M, 3)
    (workpiece frame) with the rotary axes at ``rotary_deg`` (M, n_rotary). At fixed rotary angles the tool point
    is affine in the linear commands (prismatic joints translate), so three unit steps give the map exactly."""
    rot = np.atleast_2d(np.asarray(rotary_deg, float))
    pts = np.atleast_2d(np.asarray(points_mm, float))
    lin = [machine.axes.index(a) for a in machine.linear]
    ang = [machine.axes.index(a) for a in machine.rotary]
    cmd = np.zeros((len(pts), len(machine.axes)))
    cmd[:, ang] = rot
    p0 = _tool_points(machine, cmd, offset_mm)
    J = np.stack([_tool_points(machine, cmd + np.eye(len(machine.axes))[k], offset_mm) - p0 for k in lin], axis=-1)
    cmd[:, lin] = np.linalg.solve(J, (pts - p0)[..., None])[..., 0]
    return cmd


def _tool_points(machine, cmd, offset_mm):
    """The twin's loop without the travel check (a trial command may be outside it)."""
    from olti_drake.model.five_axis import motion

    R = np.broadcast_to(np.eye(3), (len(cmd), 3, 3))
    o = np.zeros((len(cmd), 3))
    for e in machine.loop:
        Re, oe = (e[:3, :3], e[:3, 3]) if isinstance(e, np.ndarray) else motion(e, cmd[:, e.column])
        o = o + np.einsum("mij,mj->mi", R, np.broadcast_to(oe, o.shape))
        R = R @ Re
    return o + np.einsum("mij,j->mi", R, np.asarray(offset_mm, float))


def _within(machine, cmd) -> np.ndarray:
    return np.all((cmd >= machine.lower - 1e-9) & (cmd <= machine.upper + 1e-9), axis=1)


def _ranges(machine: FiveAxisMachine, ranges_deg: Dict[str, Sequence[float]], where: str) -> np.ndarray:
    """(n_rotary, 2) sweep ranges (deg): ``ranges_deg[letter]`` or the travel (a continuous axis: ±180)."""
    out = []
    for a in machine.rotary:
        k = machine.axes.index(a)
        lo, hi = (float(v) for v in ranges_deg.get(a, (max(machine.lower[k], -180.0), min(machine.upper[k], 180.0))))
        if not (np.isfinite(lo) and np.isfinite(hi) and machine.lower[k] - 1e-9 <= lo < hi <= machine.upper[k] + 1e-9):
            raise InputError(f"{where}: ranges_deg {a} = [{lo:g}, {hi:g}] must be increasing within the travel "
                             f"[{machine.lower[k]:g}, {machine.upper[k]:g}] deg")
        out.append((lo, hi))
    unknown = sorted(set(ranges_deg) - set(machine.rotary))
    if unknown:
        raise InputError(f"{where}: ranges_deg names {unknown[0]!r}, not a rotary axis of the machine "
                         f"({', '.join(machine.rotary)})")
    return np.array(out).reshape(-1, 2)


def _sweep(lo_hi: np.ndarray, n: int, rng) -> np.ndarray:
    """(2n, n_rotary): per axis n angles drawn in its range, ascending, then n more descending (forward, back)."""
    up = np.sort(rng.uniform(lo_hi[:, 0], lo_hi[:, 1], (n, len(lo_hi))), axis=0)
    down = np.sort(rng.uniform(lo_hi[:, 0], lo_hi[:, 1], (n, len(lo_hi))), axis=0)[::-1]
    return np.vstack([up, down])


def tracking_program(machine: FiveAxisMachine, n_poses: int, box_mm, ranges_deg=None, offset_mm=(0.0, 0.0, 0.0),
                     seed: int = 0, where: str = "tracking") -> np.ndarray:
    """(n_poses, n_axes) commands: rotary angles swept forward then back over ``ranges_deg`` (deg; default the
    travel), nominal tool points (``offset_mm``) drawn uniformly in ``box_mm`` [[x0, x1], [y0, y1], [z0, z1]]
    (workpiece frame), the linear axes solved for them; a pose outside the travel is drawn again (seeded)."""
    n_poses = int(n_poses)
    if n_poses < 2:
        raise InputError(f"{where}: poses must be >= 2, got {n_poses}")
    check_allocation(f"{where}: poses", n_poses, [float(n_poses), MAX_DRAWS, 64], what="values (poses x draws)",
                     hint="use fewer poses")
    box = np.asarray(box_mm, float)
    if box.shape != (3, 2) or not np.all(np.isfinite(box)) or np.any(box[:, 0] > box[:, 1]):
        raise InputError(f"{where}: box_mm must be [[x0, x1], [y0, y1], [z0, z1]] with x0 <= x1 ..., got {box_mm!r}")
    rng = np.random.default_rng(seed)
    rot = _sweep(_ranges(machine, dict(ranges_deg or {}), where), (n_poses + 1) // 2, rng)[:n_poses]
    cmd = np.full((n_poses, len(machine.axes)), np.nan)
    todo = np.arange(n_poses)
    for _ in range(MAX_DRAWS):
        trial = linear_for_points(machine, rot[todo], rng.uniform(box[:, 0], box[:, 1], (len(todo), 3)), offset_mm)
        ok = _within(machine, trial)
        cmd[todo[ok]] = trial[ok]
        todo = todo[~ok]
        if not len(todo):
            return cmd
    raise InputError(f"{where}: pose {todo[0]} (rotary {np.round(rot[todo[0]], 3).tolist()} deg) has no nominal "
                     f"tool point of box_mm within the linear travel after {MAX_DRAWS} draws; use a smaller box or "
                     f"narrower ranges_deg")


def tracking_plan(machine: FiveAxisMachine, station_frames: Sequence[str], n_poses: int, box_mm, ranges_deg=None,
                  tools: Sequence[int] = (0,), tool_offsets_mm=((0.0, 0.0, 0.0),), seed: int = 0,
                  where: str = "tracking") -> FiveAxisPlan:
    """The open-loop tracking-interferometer campaign: the program of :func:`tracking_program` (for tool
    ``tools[0]``'s nominal offset) run once per station set-up and per tool, station-major. Stations are fixed
    on the bed (``'base'``) or ride on the table (``'workpiece'``), one entry of ``station_frames`` each."""
    frames = tuple(station_frames)
    bad = [f for f in frames if f not in STATION_FRAMES]
    if not frames or bad:
        raise InputError(f"{where}: station frames must be 'base' or 'workpiece' (at least one station), got "
                         f"{list(frames)!r}")
    tools = np.asarray(tools, int).reshape(-1)
    offsets = np.asarray(tool_offsets_mm, float).reshape(-1, 3)
    if not len(tools) or tools.min() < 0 or tools.max() >= len(offsets):
        raise InputError(f"{where}: tools must be indices 0..{len(offsets) - 1} of the tool offsets, got "
                         f"{tools.tolist()}")
    prog = tracking_program(machine, n_poses, box_mm, ranges_deg, offsets[tools[0]], seed, where)
    runs = len(frames) * len(tools)
    check_allocation(f"{where}: poses", n_poses, [float(n_poses), runs, 64], what="values (rows)",
                     hint="use fewer poses, stations or tools")
    n = len(prog)
    return _rows(machine, np.tile(prog, (runs, 1)), np.tile(np.repeat(tools, n), len(frames)),
                 np.repeat(np.arange(len(frames)), n * len(tools)), np.full(n * runs, -1), frames)


def rtest_plan(machine: FiveAxisMachine, nests_mm, steps: int, ranges_deg=None, tool: int = 0,
               tool_offsets_mm=((0.0, 0.0, 0.0),), where: str = "rtest") -> FiveAxisPlan:
    """ISO 10791-6 K4-like R-test paths: per nest (N_n, 3) mm (workpiece frame), ``steps`` poses with every rotary
    axis moving together from the low to the high end of its ``ranges_deg`` (deg) and ``steps`` back, the linear
    axes following so the nominal ball centre (tool ``tool``) stays on the nest. Deterministic (no draw)."""
    nests = np.asarray(nests_mm, float)
    steps = int(steps)
    if nests.ndim != 2 or nests.shape[1:] != (3,) or not len(nests) or not np.all(np.isfinite(nests)):
        raise InputError(f"{where}: nests_mm must be a non-empty list of finite [x, y, z], got {nests_mm!r}")
    if steps < 2:
        raise InputError(f"{where}: steps must be >= 2, got {steps}")
    check_allocation(f"{where}: steps", steps, [float(steps), 2 * len(nests), 64], what="values (rows)",
                     hint="use fewer steps")
    offsets = np.asarray(tool_offsets_mm, float).reshape(-1, 3)
    if not 0 <= int(tool) < len(offsets):
        raise InputError(f"{where}: tool must be an index 0..{len(offsets) - 1} of the tool offsets, got {tool!r}")
    rot = _forth_and_back(_ranges(machine, dict(ranges_deg or {}), where), steps)
    cmds = [_following(machine, rot, p, offsets[int(tool)], f"{where}: nest {n}") for n, p in enumerate(nests)]
    m = len(rot)
    plan = _rows(machine, np.vstack(cmds), np.full(m * len(nests), int(tool)), np.full(m * len(nests), -1),
                 np.repeat(np.arange(len(nests)), m), ())
    plan.nests_mm = nests
    return plan


def _forth_and_back(lo_hi: np.ndarray, steps: int) -> np.ndarray:
    """(2 steps, n_rotary) deg: every rotary axis from the low to the high end of its range in ``steps`` poses,
    then back."""
    up = lo_hi[:, 0] + np.linspace(0.0, 1.0, steps)[:, None] * np.diff(lo_hi, axis=1)[:, 0]
    return np.vstack([up, up[::-1]])


def _following(machine, rot, point, offset, where: str) -> np.ndarray:
    """Commands at the rotary poses ``rot`` with the linear axes keeping the nominal tool point ``offset`` on
    ``point`` (workpiece frame, mm); a pose needing linear commands outside the travel refused in one line."""
    c = linear_for_points(machine, rot, np.broadcast_to(point, (len(rot), 3)), offset)
    ok = _within(machine, c)
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])
        raise InputError(f"{where} at {np.asarray(point).tolist()} mm: pose {k} (rotary "
                         f"{np.round(rot[k], 3).tolist()} deg) needs linear commands outside the travel; move it or "
                         f"narrow ranges_deg")
    return c


def bk_paths(machine: FiveAxisMachine, ball_mm, steps: int, ranges_deg=None, hold_deg=None, tool: int = 0,
             tool_offsets_mm=((0.0, 0.0, 0.0),), where: str = "bk") -> FiveAxisPlan:
    """ISO 10791-6 BK-type paths around one ball (its centre ``ball_mm`` in the workpiece frame, mm): per rotary
    axis in turn, that axis alone from the low to the high end of its ``ranges_deg`` (deg; default the travel) in
    ``steps`` poses and back, the others held at ``hold_deg`` (default 0, within the travel); then all of them
    together (K4-like); the linear axes following so the nominal tool point (tool ``tool``) stays on the ball.
    ``nest`` is the path's index, ``nests_mm`` the ball per path, ``path_names`` e.g. 'C alone', 'A+C'.
    Deterministic (no draw)."""
    ball = np.asarray(ball_mm, float).reshape(-1)
    steps = int(steps)
    if ball.shape != (3,) or not np.all(np.isfinite(ball)) or steps < 2:
        raise InputError(f"{where}: ball_mm must be a finite [x, y, z] and steps >= 2, got {ball_mm!r}, {steps}")
    check_allocation(f"{where}: steps", steps, [float(steps), 2 * (len(machine.rotary) + 1), 64], what="values "
                     "(rows)", hint="use fewer steps")
    offsets = np.asarray(tool_offsets_mm, float).reshape(-1, 3)
    lo_hi = _ranges(machine, dict(ranges_deg or {}), where)
    k = [machine.axes.index(a) for a in machine.rotary]
    hold = np.array([float(dict(hold_deg or {}).get(a, 0.0)) for a in machine.rotary])
    hold = np.clip(hold, machine.lower[k], machine.upper[k])
    sweep = _forth_and_back(lo_hi, steps)
    paths = [np.where(np.arange(len(k)) == j, sweep, hold) for j in range(len(k))] + [sweep]
    names = [f"{a} alone" for a in machine.rotary] + ["+".join(machine.rotary)]
    cmds = [_following(machine, rot, ball, offsets[int(tool)], f"{where}: path {n}") for n, rot in zip(names, paths)]
    m = len(sweep)
    plan = _rows(machine, np.vstack(cmds), np.full(m * len(paths), int(tool)), np.full(m * len(paths), -1),
                 np.repeat(np.arange(len(paths)), m), ())
    plan.nests_mm = np.tile(ball, (len(paths), 1))
    plan.path_names = tuple(names)
    return plan


def _rows(machine, commands, tool, station, nest, frames) -> FiveAxisPlan:
    return FiveAxisPlan(tuple(machine.axes), commands, approach_directions(commands, commands[0] - 1.0), tool,
                        station, nest, tuple(frames))


def combine(*plans: FiveAxisPlan) -> FiveAxisPlan:
    """The plans in execution order as one campaign: rows concatenated, the approach directions taken again over
    the whole sequence (an axis that did not move keeps its last direction; the first approach is positive)."""
    plans = [p for p in plans if p is not None and len(p)]
    if not plans:
        raise InputError("five-axis plan: no rows (neither stations nor nests)")
    cmd = np.vstack([p.commands for p in plans])
    frames = next((p.station_frames for p in plans if p.station_frames), ())
    nests = next((p.nests_mm for p in plans if len(p.nests_mm)), np.zeros((0, 3)))
    return FiveAxisPlan(plans[0].axes, cmd, approach_directions(cmd, cmd[0] - 1.0),
                        np.concatenate([p.tool for p in plans]), np.concatenate([p.station for p in plans]),
                        np.concatenate([p.nest for p in plans]), frames, nests)


__all__ = ["FiveAxisPlan", "STATION_FRAMES", "bk_paths", "combine", "linear_for_points", "rtest_plan",
           "tracking_plan", "tracking_program"]
