"""Measurement plans for N-joint serial robots read by floor tracers, and their predicted quality.

A plan is a sequence of measured poses (joint commands, deg) with the approach direction of
every joint and the stations that can read each pose. :func:`generate_plan` builds one under
these rules (docs/six_axis_campaign.md):

* **Nodes** — per joint, the map nodes are the multiples of ``step_deg`` inside the joint's
  plan range: the user range (default the model's limits, ±180° where unlimited) intersected
  with the limits shrunk by the approach overrun. Every measured pose puts every joint exactly
  on one of its nodes (a reading then touches one node per joint, 000 Eq. (7) with α = 0).
* **Approach** — before every measured pose q the robot goes to the approach pose
  q − ``overrun_deg``·dir (all joints at once, not measured), then to q: the last motion of
  joint i has the sign dir_i, whatever pose came before (the rule of errormap.approach_directions
  applied to the sequence approach, pose, approach, pose, ...; :meth:`SerialPlan.motion_sequence`).
  The shrunk range keeps every approach pose inside the limits, so both directions are possible
  at every node. Coverage asks ``poses_per_node`` poses per (joint, node, direction).
* **Line of sight and acceptance** — a pose is read from station j when the beam from the
  station centre to the cat's eye clears the arm — capsules of radius ``link_radius_mm`` around
  the segments joining consecutive joint-frame origins, the tool-frame origin and the tool point
  (nominal chain FK; a simple capsule approximation, not the model's collision geometry), the
  last ``clearance_mm`` before the cat's eye excepted — and arrives within ±80° of the cat's-eye
  axis (a direction in the tool frame); poses with a capsule point below ``floor_z_mm`` are
  rejected. A pose needs ``min_stations`` readable stations, else it is not used.
* **Ordering** — greedy nearest neighbour in joint space (Euclidean, deg, seeded start) and a
  2-opt pass, to keep robot travel short.

:func:`plan_report` predicts, before any measurement, what the plan can identify by the linear
method: the serial.py position model (error maps on the plan's nodes, bidirectional) with
distance readings from the stations (000 Eq. (10) in 3D, station positions and dead paths
free), the gauge of :func:`~olti_drake.model.serial.find_gauge`, a reading standard uncertainty
u (the budget's ``reading`` and ``pose`` contributors, root-sum-squared): rank of the Jacobian
with the gauge, its condition number (unit-scaled columns), the predicted standard uncertainties
of the map nodes per joint (max / median) and the parameters the plan cannot identify, by name.

Units: mm and degrees.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import scipy.linalg

from olti_drake.model.aiming3d import MAX_VIEWING_DEG, _unit
from olti_drake.model.chain import UNLIMITED_RANGE_DEG, SerialChain
from olti_drake.model.serial import DistanceMeasurement, build_position_model, find_gauge

#: A plan parameter's unseen share above this (of its unit-scaled null direction) names it unidentifiable.
UNSEEN_SHARE = 0.1


@dataclass(frozen=True)
class PlanRules:
    """What :func:`generate_plan` must satisfy (mm, deg). ``ranges_deg`` (N, 2) or None (limits)."""

    step_deg: float = 15.0
    ranges_deg: Optional[np.ndarray] = None
    overrun_deg: float = 1.0
    poses_per_node: int = 2
    min_stations: int = 2
    link_radius_mm: float = 45.0
    clearance_mm: float = 60.0
    catseye_axis_tool: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    floor_z_mm: Optional[float] = None
    max_batches: int = 200
    batch: int = 256


@dataclass(frozen=True, eq=False)
class SerialPlan:
    """Measured poses in order: ``commands_deg`` (M, N), ``dirs`` (M, N) ±1, ``visible`` (M, Nt)
    which stations read each pose, ``grids`` per joint (the map nodes), ``overrun_deg``."""

    joint_names: Tuple[str, ...]
    commands_deg: np.ndarray
    dirs: np.ndarray
    visible: np.ndarray
    grids: Dict[str, np.ndarray]
    overrun_deg: float

    @property
    def n_readings(self) -> int:
        return int(self.visible.sum())

    def readings(self):
        """(pose index, station) of every reading, station by station."""
        st, pose = np.nonzero(self.visible.T)
        return pose, st

    def motion_sequence(self) -> np.ndarray:
        """(2M, N): approach pose then measured pose, for every pose in order (what the robot does)."""
        seq = np.empty((2 * len(self.commands_deg), self.commands_deg.shape[1]))
        seq[0::2] = self.commands_deg - self.overrun_deg * self.dirs
        seq[1::2] = self.commands_deg
        return seq

    def travel_deg(self) -> float:
        """Σ ‖q_k+1 − q_k‖ over the measured poses in order (deg, Euclidean in joint space)."""
        return float(np.linalg.norm(np.diff(self.commands_deg, axis=0), axis=1).sum())

    def coverage(self) -> Dict[str, np.ndarray]:
        """Per joint: (n_nodes, 2) readings at each node approached +1 (column 0) and −1 (column 1)."""
        pose, _ = self.readings()
        out = {}
        for i, name in enumerate(self.joint_names):
            g = self.grids[name]
            at = np.abs(self.commands_deg[pose, i][:, None] - g[None, :]) < 1e-9
            plus = self.dirs[pose, i] > 0
            out[name] = np.column_stack([at[plus].sum(axis=0), at[~plus].sum(axis=0)])
        return out


# ---------------------------------------------------------------- geometry
def plan_ranges(chain: SerialChain, rules: PlanRules) -> np.ndarray:
    """(N, 2) deg: the user range within the limits shrunk by the overrun (see module doc)."""
    lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg + rules.overrun_deg, -UNLIMITED_RANGE_DEG)
    hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg - rules.overrun_deg, UNLIMITED_RANGE_DEG)
    if rules.ranges_deg is not None:
        user = np.asarray(rules.ranges_deg, float).reshape(chain.n_joints, 2)
        lo, hi = np.maximum(lo, user[:, 0]), np.minimum(hi, user[:, 1])
    bad = np.flatnonzero(lo > hi)
    if len(bad):
        raise ValueError(f"plan range of {chain.joint_names[bad[0]]}: empty within the joint limits "
                         f"less the {rules.overrun_deg:g} deg approach overrun")
    return np.column_stack([lo, hi])


def node_grid(step_deg: float, lo: float, hi: float) -> np.ndarray:
    """Multiples of ``step_deg`` inside [lo, hi] deg (at least the nearest one to the middle)."""
    if not (np.isfinite(step_deg) and step_deg > 0):
        raise ValueError(f"plan step_deg: must be a positive number of degrees, got {step_deg!r}")
    g = step_deg * np.arange(np.ceil(lo / step_deg - 1e-9), np.floor(hi / step_deg + 1e-9) + 1)
    return g if g.size else np.array([np.clip(step_deg * np.round((lo + hi) / 2 / step_deg), lo, hi)])


def link_points(chain: SerialChain, commands_deg, tool_offset_mm) -> np.ndarray:
    """(M, N + 2, 3) mm: the joint-frame origins, the tool-frame origin and the tool point
    (nominal chain), each from a sub-chain's FK (the chain's own vectorized model)."""
    th = np.atleast_2d(np.asarray(commands_deg, float))
    pts = [np.broadcast_to(chain.fixed_mm[0][:3, 3], (len(th), 3))]
    for i in range(1, chain.n_joints + 1):
        fixed = np.concatenate([chain.fixed_mm[:i], chain.fixed_mm[i][None]])
        sub = dataclasses.replace(chain, joint_names=chain.joint_names[:i], fixed_mm=fixed,
                                  axes=chain.axes[:i], lower_deg=chain.lower_deg[:i],
                                  upper_deg=chain.upper_deg[:i])
        pts.append(sub.positions(th[:, :i]))
    pts.append(chain.positions(th, chain.nominal_parameters(tool_offset_mm)))
    return np.stack(pts, axis=1)


def segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Smallest distance between segments p0–p1 and q0–q1 (broadcast over leading axes), mm.
    Closest points by Ericson's clamped solution (Real-Time Collision Detection §5.1.9),
    degenerate (point) segments included."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e = np.sum(d1 * d1, -1), np.sum(d2 * d2, -1)
    b, c, f = np.sum(d1 * d2, -1), np.sum(d1 * r, -1), np.sum(d2 * r, -1)
    tiny = 1e-12
    a_, e_ = np.where(a > tiny, a, 1.0), np.where(e > tiny, e, 1.0)
    den = a * e - b * b
    s = np.where(den > tiny * a_ * e_, np.clip((b * f - c * e) / np.where(den > 0, den, 1.0), 0, 1), 0.0)
    t = (b * s + f) / e_
    s = np.where(t < 0, np.clip(-c / a_, 0, 1), np.where(t > 1, np.clip((b - c) / a_, 0, 1), s))
    t = np.clip(t, 0, 1)
    # a point segment: the closest point on the other is its clamped projection
    s = np.where(e <= tiny, np.clip(-c / a_, 0, 1), s)
    t = np.where(e <= tiny, 0.0, t)
    t = np.where(a <= tiny, np.clip(f / e_, 0, 1), t)
    s = np.where(a <= tiny, 0.0, s)
    return np.linalg.norm(p0 + s[..., None] * d1 - q0 - t[..., None] * d2, axis=-1)


def readable(chain: SerialChain, commands_deg, stations_mm, rules: PlanRules, tool_offset_mm) -> np.ndarray:
    """(M, Nt) bool: line of sight past the arm's capsules and the cat's eye within ±80°."""
    pts = link_points(chain, commands_deg, tool_offset_mm)
    tip = pts[:, -1]
    params = chain.nominal_parameters(np.asarray(tool_offset_mm, float) + _unit(rules.catseye_axis_tool))
    axis = chain.positions(commands_deg, params) - tip
    ok = np.ones((len(tip), len(stations_mm)), bool)
    for j, station in enumerate(np.asarray(stations_mm, float)):
        beam = tip - station
        length = np.linalg.norm(beam, axis=1, keepdims=True)
        ok[:, j] &= np.degrees(np.arccos(np.clip(np.sum(axis * -beam / length, 1), -1, 1))) <= MAX_VIEWING_DEG
        end = tip - beam / length * rules.clearance_mm
        dist = segment_distance(np.broadcast_to(station, pts[:, :-1].shape), end[:, None], pts[:, :-1], pts[:, 1:])
        ok[:, j] &= dist.min(axis=1) > rules.link_radius_mm
    if rules.floor_z_mm is not None:
        ok &= (pts[:, 1:, 2].min(axis=1) > rules.floor_z_mm)[:, None]
    return ok


# --------------------------------------------------------------- generator
def generate_plan(chain: SerialChain, stations_mm, rules: PlanRules = PlanRules(), *,
                  tool_offset_mm=(0.0, 0.0, 0.0), seed: int = 0) -> SerialPlan:
    """A plan covering every (joint, node, direction) ``rules.poses_per_node`` times with poses
    readable from ≥ ``rules.min_stations`` stations (module doc), ordered for short travel.

    Batches of candidate poses draw, per joint, a (node, direction) with probability ∝ the
    pair's remaining deficit (+ a small floor, so covered pairs still vary); readable candidates
    are kept while they lower some deficit. Raises ValueError naming the joint, node and
    direction still uncovered after ``rules.max_batches`` batches (e.g. always out of sight)."""
    stations = np.atleast_2d(np.asarray(stations_mm, float))
    if rules.min_stations > len(stations):
        raise ValueError(f"plan min_stations {rules.min_stations}: only {len(stations)} stations")
    rng = np.random.default_rng(seed)
    ranges = plan_ranges(chain, rules)
    grids = {name: node_grid(rules.step_deg, *ranges[i]) for i, name in enumerate(chain.joint_names)}
    need = [np.full((g.size, 2), rules.poses_per_node) for g in grids.values()]
    kept_cmd, kept_dir, kept_vis = [], [], []
    for _ in range(rules.max_batches):
        if all(np.all(d <= 0) for d in need):
            break
        cmd, dirs, picks = _draw(grids, need, rules.batch, rng)
        vis = readable(chain, cmd, stations, rules, tool_offset_mm)
        for k in np.flatnonzero(vis.sum(axis=1) >= rules.min_stations):
            if any(need[i][picks[k, i, 0], picks[k, i, 1]] > 0 for i in range(chain.n_joints)):
                for i in range(chain.n_joints):
                    need[i][picks[k, i, 0], picks[k, i, 1]] -= 1
                kept_cmd.append(cmd[k]), kept_dir.append(dirs[k]), kept_vis.append(vis[k])
    for i, name in enumerate(chain.joint_names):
        left = np.argwhere(need[i] > 0)
        if len(left):
            node, d = left[0]
            raise ValueError(f"plan: joint {name} node {grids[name][node]:g} deg direction "
                             f"{'+1' if d == 0 else '-1'} not covered: no readable pose found in "
                             f"{rules.max_batches} batches (line of sight, viewing angle, floor)")
    cmd, dirs, vis = np.array(kept_cmd), np.array(kept_dir), np.array(kept_vis)
    order = order_poses(cmd, seed=seed)
    return SerialPlan(chain.joint_names, cmd[order], dirs[order], vis[order], grids, rules.overrun_deg)


def _draw(grids, need, count, rng):
    """``count`` candidate poses: per joint a (node, dir) drawn ∝ deficit + 0.05."""
    n = len(grids)
    picks = np.empty((count, n, 2), int)
    cmd = np.empty((count, n))
    for i, g in enumerate(grids.values()):
        w = np.maximum(need[i], 0).ravel() + 0.05
        flat = rng.choice(w.size, size=count, p=w / w.sum())
        picks[:, i, 0], picks[:, i, 1] = np.divmod(flat, 2)
        cmd[:, i] = g[picks[:, i, 0]]
    return cmd, np.where(picks[:, :, 1] == 0, 1.0, -1.0), picks


def order_poses(commands_deg, *, seed: int = 0, max_passes: int = 20) -> np.ndarray:
    """An order of the poses with short joint-space travel: greedy nearest neighbour from a
    seeded start, then 2-opt (reverse a stretch when that shortens the path) until no gain."""
    q = np.asarray(commands_deg, float)
    m = len(q)
    if m < 3:
        return np.arange(m)
    dist = _pairwise(q)
    start = int(np.random.default_rng(seed).integers(m))
    order, free = [start], np.ones(m, bool)
    free[start] = False
    for _ in range(m - 1):
        d = np.where(free, dist[order[-1]], np.inf)
        nxt = int(np.argmin(d))
        order.append(nxt)
        free[nxt] = False
    order = np.array(order)
    for _ in range(max_passes):
        improved = False
        for i in range(m - 2):
            a, b = order[i], order[i + 1]
            c, d = order[i + 2:], np.append(order[i + 3:], -1)
            new = dist[a, c] + np.where(d >= 0, dist[b, d], 0.0)
            old = dist[a, b] + np.where(d >= 0, dist[c, d], 0.0)
            gain = old - new
            j = int(np.argmax(gain))
            if gain[j] > 1e-9:
                order[i + 1:i + 3 + j] = order[i + 1:i + 3 + j][::-1]
                improved = True
        if not improved:
            break
    return order


def _pairwise(q):
    sq = np.sum(q * q, axis=1)
    return np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2 * q @ q.T, 0.0))



# ------------------------------------------------------------------ report
@dataclass(frozen=True)
class PlanReport:
    """The plan's predicted quality before any measurement (linear method, module doc)."""

    coverage: Dict[str, np.ndarray]
    rank: int
    n_params: int
    condition: float
    u_reading_mm: float
    node_uncertainty_deg: Dict[str, Tuple[float, float]]
    unidentifiable: Tuple[str, ...]
    gauge: str
    dropped: Tuple[Tuple[str, str], ...] = ()

    @property
    def identifiable(self) -> bool:
        return not self.unidentifiable

    def lines(self) -> Sequence[str]:
        """The report in words, one joint per line."""
        out = [f"rank {self.rank} of {self.n_params} with the gauge; condition number {self.condition:.3g}; "
               f"u(reading) = {self.u_reading_mm * 1e3:.3g} um"]
        for name, cov in self.coverage.items():
            line = (f"{name}: {len(cov)} nodes, readings per node +1 min {cov[:, 0].min()} / -1 min "
                    f"{cov[:, 1].min()}; ")
            if name in self.node_uncertainty_deg:
                umax, umed = self.node_uncertainty_deg[name]
                line += f"u(node) max {umax * 1e3:.3g} mdeg, median {umed * 1e3:.3g} mdeg"
            out.append(line + ("" if name in self.node_uncertainty_deg else "no map"))
        out += [f"not in the model: {name} ({why})" for name, why in self.dropped if "map" in name]
        if self.unidentifiable:
            out.append("unidentifiable: " + ", ".join(self.unidentifiable))
        return out


def reading_uncertainty_mm(budget) -> float:
    """u of one distance reading from a budget: reading and pose contributors, root-sum-squared (mm)."""
    return float(np.hypot(budget.combined("reading"), budget.combined("pose")))


def plan_report(chain: SerialChain, plan: SerialPlan, stations_mm, u_reading_mm: float, *,
                tool_offset_mm=(0.0, 0.0, 0.0), dead_paths_mm=None, seed: int = 0) -> PlanReport:
    """Predicted identifiability and uncertainty of ``plan`` (module doc).

    The model's maps are on the plan's grids (bidirectional); the station positions are the
    estimates ``stations_mm`` (Nt, 3). With J the unit-scaled Jacobian of all readings and Z a
    basis of the gauge constraints' null space: rank = rank(J Z) + gauge count, condition =
    cond(J Z), covariance = u² Z (Zᵀ JᵀJ Z)⁺ Zᵀ (unscaled). A parameter whose share of the unseen
    space of J Z exceeds ``UNSEEN_SHARE`` is named unidentifiable (its node uncertainty is inf)."""
    stations = np.atleast_2d(np.asarray(stations_mm, float))
    grids = {k: np.asarray(v, float) for k, v in plan.grids.items()}
    model = build_position_model(chain, plan.commands_deg, plan.dirs, grids=grids,
                                 tool_offset_mm=tool_offset_mm, seed=seed)
    pose, st = plan.readings()
    nt = len(stations)
    problem = DistanceMeasurement(model, plan.commands_deg[pose], plan.dirs[pose], st, np.zeros(len(st)),
                                  stations, np.zeros(nt) if dead_paths_mm is None else dead_paths_mm)
    gauge = find_gauge(problem, seed=seed)
    _, jac = problem.residuals(problem.start_vector())
    jac = jac.toarray()
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    z = scipy.linalg.null_space(gauge.A / scale) if len(gauge.constraints) else np.eye(jac.shape[1])
    jz = (jac / scale) @ z
    _, s, vt = np.linalg.svd(jz, full_matrices=jz.shape[0] < jz.shape[1])
    s = np.concatenate([s, np.zeros(vt.shape[0] - s.size)])
    tol = s[0] * max(jz.shape) * np.finfo(float).eps * 1e3
    seen = s > tol
    rank = int(seen.sum())
    unseen = _unseen(z @ vt[~seen].T, problem.names)
    cov = z @ (vt[seen].T / s[seen] ** 2) @ vt[seen] @ z.T  # (Zᵀ JᵀJ Z)⁺ in the seen space
    std = u_reading_mm * np.sqrt(np.maximum(np.diag(cov), 0.0)) / scale
    names = list(problem.names)
    node_u = {}
    for m, start in zip(model.maps, model.map_starts):
        vals = std[start:start + m.n_values]
        blind = [names[start + c] in unseen for c in range(m.n_values)]
        vals = np.where(blind, np.inf, vals)
        node_u[m.joint] = (float(vals.max()), float(np.median(vals)))
    cond = float(s[0] / s[rank - 1]) if rank == len(s) else np.inf
    return PlanReport(plan.coverage(), rank + len(gauge.constraints), jac.shape[1], cond,
                      u_reading_mm, node_u, unseen, gauge.sentence, tuple(model.dropped))


def _unseen(null, names) -> Tuple[str, ...]:
    """Names of parameters whose share of the unseen space (``null``: an orthonormal basis in
    unit-scaled parameters; the share is its row norm: 1 = nothing of the parameter is seen,
    1/√2 = it trades with one other) exceeds ``UNSEEN_SHARE``."""
    if null.size == 0:
        return ()
    share = np.linalg.norm(null, axis=1)
    return tuple(n for n, v in zip(names, share) if v > UNSEEN_SHARE)
