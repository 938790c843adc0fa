"""Station placement design in 3D for N-joint robots read by floor tracers (000 §3.2.2 Remark 2 in 3D).

000 §3.2.2 Remark 2: where the stations stand decides how well the campaign locates the tool, and
"the uncertainty analysis (§5) is essential for the design". For a robot loaded from a model file
this module chooses station positions among candidates in 3D boxes so that the predicted tool-point
uncertainty over the workspace is smallest, by the linear method (JCGM 100), before any measurement:

* **Information per station.** A station at P reads, for every plan pose it can see (the
  line-of-sight and ±80° acceptance rules of :func:`~olti_drake.estimation.serial_plan.readable`),
  d_k = ‖p_k − P‖ − d0 (000 Eq. (10) in 3D) with standard uncertainty u (the budget's reading and pose
  contributors). Its own unknowns (P, d0) are eliminated by the Schur complement, so its
  information on the model parameters θ is S(P) = (J_θᵀJ_θ − J_θᵀJ_s (J_sᵀJ_s)⁻¹ J_sᵀJ_θ)/u², and a
  layout's information is the *sum* over its stations: each candidate is evaluated once.
* **Cost.** With Z a basis of the null space of the model's gauge constraints
  (:func:`~olti_drake.model.serial.find_gauge`: the rigid motion distances cannot see and the zeros
  that trade with the tool), cov θ = Z (Zᵀ S Z)⁻¹ Zᵀ; the predicted tool point p(q) over seeded
  workspace poses has u(q) = sqrt(trace(J_p(q) cov J_p(q)ᵀ)) (mm, k = 1); the cost is its maximum
  or mean. A layout whose Zᵀ S Z is singular (a parameter not seen) costs infinity.
* **Search.** Coordinate exchange from seeded random starts: replace one station at a time by the
  feasible candidate that lowers the cost most, until a sweep brings nothing; stations keep
  ``min_separation_mm`` from each other.

Units: mm and degrees; uncertainties standard (k = 1) unless said otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import scipy.linalg

from olti_drake.errors import InputError
from olti_drake.formats import DESIGN as FORMAT
from olti_drake.estimation.design import BASE_RADIUS_MM, CLEARANCE_MM, beam_axis_distances
from olti_drake.estimation.serial_plan import PlanRules, readable
from olti_drake.estimation.station_information import predicted_u, station_information
from olti_drake.io.csvio import read_yaml
from olti_drake.model.chain import plane_frame
from olti_drake.model.serial import DistanceMeasurement, SerialPositionModel, find_gauge
from olti_drake.threads import single_thread_blas
from olti_drake.units import unit_bound

#: Default minimum distance between two stations, mm.
MIN_SEPARATION_MM = 300.0
#: A station reading fewer poses than this tells nothing beyond its own four unknowns: not a candidate.
MIN_READINGS = 12


def load_boxes(path) -> np.ndarray:
    """(B, 3, 2) boxes [[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]] mm from a regions YAML:
    ``regions: [{x_mm: [lo, hi], y_mm: [lo, hi], z_mm: [lo, hi]}, ...]`` (z_mm may be one value,
    e.g. the floor height: [z, z])."""
    doc = read_yaml(path, "a regions file")
    regions = doc.get("regions") if isinstance(doc, dict) else None
    if not isinstance(regions, list) or not regions:
        raise InputError(f"{path}: expected 'regions:' with a list of boxes {{x_mm: [lo, hi], y_mm: [lo, hi], "
                         f"z_mm: [lo, hi]}}")
    out = []
    for i, reg in enumerate(regions):
        box = []
        for key in ("x_mm", "y_mm", "z_mm"):
            v = reg.get(key) if isinstance(reg, dict) else None
            if isinstance(v, (int, float)):
                v = [v, v]
            try:
                lo, hi = (float(a) for a in v)
            except (TypeError, ValueError):
                raise InputError(f"{path}: regions[{i}].{key} must be [lo, hi] in mm (3D design needs x_mm, y_mm "
                                 f"and z_mm), got {v!r}") from None
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi) or max(abs(lo), abs(hi)) > unit_bound(key):
                raise InputError(f"{path}: regions[{i}].{key} = [{lo:g}, {hi:g}] must be finite, lo <= hi, within "
                                 f"±{unit_bound(key):g} mm")
            box.append((lo, hi))
        out.append(box)
    return np.asarray(out, float)


def candidate_points(boxes, step_mm: float) -> np.ndarray:
    """(C, 3) candidate station positions on a ``step_mm`` grid inside every box (its ends included)."""
    if not (np.isfinite(step_mm) and step_mm > 0):
        raise InputError(f"--step-mm must be > 0, got {step_mm:g}")
    pts = []
    for box in np.asarray(boxes, float):
        sizes = [math.floor((hi - lo + 1e-9) / step_mm) + 1 if hi > lo else 1 for lo, hi in box]  # before arange
        if math.prod(float(k) for k in sizes) > 200_000:
            raise InputError(f"--step-mm {step_mm:g}: {math.prod(float(k) for k in sizes):.3g} candidates in one "
                             f"region, more than 200000; use a larger step")
        axes = [np.arange(lo, hi + 1e-9, step_mm) if hi > lo else np.array([lo]) for lo, hi in box]
        pts.append(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3))
    return np.unique(np.vstack(pts), axis=0)


def planar_readable(tool_mm, station_mm, plane, axis_point_mm, base_radius_mm: float, clearance_mm: float,
                    arm_mm=None) -> np.ndarray:
    """(K,) bool: which tool points (K, 3) a station in a planar robot's plane reads -- the rules of the SCARA's
    design (:func:`~olti_drake.estimation.design.feasible_candidates`), in the plane: the beam is steered at
    the station (000 Eq. (1): no acceptance cone on the tool), it passes no closer than ``base_radius_mm`` to
    the first joint's axis (through ``axis_point_mm``: the base column; 0 turns it off), and the station keeps
    ``clearance_mm`` from every point the tool goes to (``arm_mm``, default the tool points): else it reads
    none."""
    E = plane_frame(plane)[1]
    q = (np.asarray(tool_mm, float) - axis_point_mm) @ E
    s = (np.asarray(station_mm, float) - axis_point_mm) @ E
    arm = q if arm_mm is None else (np.asarray(arm_mm, float) - axis_point_mm) @ E
    if np.min(np.linalg.norm(arm - s, axis=1)) < clearance_mm:
        return np.zeros(len(q), bool)
    return beam_axis_distances(q, s)[0] >= base_radius_mm if base_radius_mm > 0 else np.ones(len(q), bool)


def candidates_in_plane(candidates_mm, plane, level_mm: float, step_mm: float, regions: str = "the regions"):
    """A planar model's stations stand in its plane (the planar problem: beams in the plane, 000): the
    candidates within half a grid step of the plane (normal of ``plane`` at ``level_mm`` along it), moved onto
    it, (C, 3) mm. One line naming the plane when the regions do not reach it."""
    n, C = plane_frame(plane)[0], np.asarray(candidates_mm, float)
    off = C @ n - level_mm
    near = np.abs(off) <= 0.5 * step_mm + 1e-9
    if not near.any():
        raise InputError(f"{regions}: no candidate lies within half a step ({0.5 * step_mm:g} mm) of the robot's plane "
                         f"(normal ({', '.join(f'{c:.4g}' for c in n)}) at {level_mm:.6g} mm along it): a planar "
                         f"robot's stations stand in its plane -- give regions that cross it")
    return np.unique(C[near] - np.outer(off[near], n), axis=0)


def workspace_poses(model: SerialPositionModel, n_poses: int, seed: int):
    """Seeded poses (n, N) deg uniform in the model's commanded ranges, random approach directions
    (None for a one-directional model): where the predicted uncertainty is evaluated."""
    rng = np.random.default_rng(seed)
    ranges = model.command_ranges()
    q = rng.uniform(ranges[:, 0], ranges[:, 1], size=(n_poses, len(ranges)))
    dirs = rng.choice([-1.0, 1.0], size=q.shape) if model.bidirectional else None
    return q, dirs


@dataclass
class StationInformation:
    """Per-station information on the model parameters for a plan (module docstring), and the cost.

    ``commands``/``dirs``: the plan's measured poses; ``u_reading_mm``: standard uncertainty of one
    reading; ``workspace``: (poses, dirs) where the cost is evaluated; ``rules``: line of sight and
    acceptance; ``gauge_rows``: (g, n) the gauge constraints on the model parameters; ``plane``: a planar
    model's plane (:func:`~olti_drake.model.chain.robot_plane`): stations in it have two in-plane
    coordinates and a dead path of their own (the planar problem's), not three coordinates, and read by
    :func:`planar_readable` (``base_radius_mm``, ``clearance_mm``) instead of ``rules``."""

    model: SerialPositionModel
    commands: np.ndarray
    dirs: Optional[np.ndarray]
    u_reading_mm: float
    workspace: tuple
    rules: PlanRules = field(default_factory=PlanRules)
    gauge_rows: Optional[np.ndarray] = None
    plane: object = None
    base_radius_mm: float = BASE_RADIUS_MM
    clearance_mm: float = CLEARANCE_MM

    def __post_init__(self):
        m = self.model
        self.p, self.jac = m.jacobian(self.commands, self.dirs)
        wp, wj = m.jacobian(*self.workspace)
        self.workspace_jacobian = wj.tocsr().toarray()  # (3K, n)
        self.tool_offset = m.chain_parameters(m.start_vector())[-3:]
        if self.gauge_rows is None:
            self.gauge_rows = np.zeros((0, m.n_params))
        self.Z = scipy.linalg.null_space(self.gauge_rows) if len(self.gauge_rows) else np.eye(m.n_params)
        self.GZ = self.workspace_jacobian @ self.Z
        self._own_axes = np.eye(3) if self.plane is None else plane_frame(self.plane)[1]  # (3, 3 or 2)
        # Where the tool goes: a planar robot's station keeps clear of it.
        self._arm = None if self.plane is None else np.vstack([self.p, wp])

    def block(self, station_mm):
        """(S (n, n) information on θ, readings) of one station at ``station_mm`` (3,) mm."""
        P = np.asarray(station_mm, float)
        ok = (readable(self.model.chain, self.commands, P[None], self.rules, self.tool_offset)[:, 0]
              if self.plane is None else
              planar_readable(self.p, P, self.plane, self.model.chain.fixed_mm[0][:3, 3], self.base_radius_mm,
                              self.clearance_mm, self._arm))
        n = self.model.n_params
        if ok.sum() < MIN_READINGS:
            return np.zeros((n, n)), int(ok.sum())
        diff = self.p[ok] - P
        u = diff / np.linalg.norm(diff, axis=1, keepdims=True)
        S = station_information(self.jac.take(ok).contract(u), u @ self._own_axes,
                                np.full(len(u), 1 / self.u_reading_mm))
        return S, int(ok.sum())

    def position_u(self, S) -> np.ndarray:
        """u (mm, k = 1) of the predicted tool point at every workspace pose for information S; inf if
        the gauge-reduced information is singular."""
        return predicted_u(S, self.Z, self.GZ)


def gauge_rows(model: SerialPositionModel, commands, dirs, stations_mm, seed: int = 0, plane=None) -> tuple:
    """The model's gauge constraints (rows on θ, sentence) for a campaign from ``stations_mm`` (``plane``: a
    planar model's, its stations in it)."""
    nt = len(stations_mm)
    reps = np.repeat(np.arange(nt), len(commands))
    meas = DistanceMeasurement(model, np.tile(commands, (nt, 1)), None if dirs is None else np.tile(dirs, (nt, 1)),
                               reps, np.zeros(len(reps)), stations_mm, np.zeros(nt), plane=plane)
    gauge = find_gauge(meas, seed=seed)
    return np.asarray(gauge.A, float)[:, :model.n_params], gauge.sentence


@dataclass
class StationDesign:
    """The designed layout and how it was found (mm; costs are u, k = 1)."""

    stations_mm: np.ndarray
    cost_mm: float
    criterion: str
    candidates_mm: np.ndarray
    readings: np.ndarray           # per candidate: readable plan poses
    evaluations: int
    starts: int
    u_mm: np.ndarray               # per workspace pose, the designed layout
    notes: list = field(default_factory=list)


def layout_cost(info: StationInformation, blocks, criterion: str) -> float:
    u = info.position_u(sum(blocks))
    return float(np.max(u) if criterion == "max" else np.mean(u))


def check_block_sizes(info, n_candidates: int) -> None:
    """Refuse (:func:`olti_drake.limits.check_allocation`), before any block is made, candidates whose dense
    per-station information (kept for every candidate: n x n, two of them for the sandwich of a machine tool)
    would allocate more than the limit."""
    from olti_drake.limits import check_allocation

    if hasattr(info, "model"):
        n, per = info.model.n_params, 1
    else:
        n, per = len(info._cols), 2
    check_allocation("--step-mm", f"({n_candidates} candidates)", [n_candidates, per, n, n],
                     what="values (candidates x per-station information n x n)",
                     hint="use a larger --step-mm or smaller regions")


def design_stations(info: StationInformation, candidates_mm, n_stations: int, *, criterion: str = "max",
                    seed: int = 0, starts: int = 3, max_sweeps: int = 5,
                    min_separation_mm: float = MIN_SEPARATION_MM,
                    progress: Optional[Callable[[int, int, float], None]] = None, **where) -> StationDesign:
    """Coordinate exchange over ``candidates_mm`` (C, 3) for ``n_stations`` stations (module docstring); ``where``:
    the starts' ``workers``, ``backend``, ``scheduler`` (:func:`coordinate_exchange`; default: this process)."""
    if criterion not in ("max", "mean"):
        raise InputError(f"criterion: 'max' or 'mean', not {criterion!r}")
    cand = np.atleast_2d(np.asarray(candidates_mm, float))
    check_block_sizes(info, len(cand))
    with single_thread_blas():  # thousands of small (n x n) products: threads only contend
        return _exchange(info, cand, n_stations, criterion, seed, starts, max_sweeps, min_separation_mm, progress,
                         where)


def _exchange(info, cand, n_stations, criterion, seed, starts, max_sweeps, min_separation_mm, progress, where):
    blocks, counts = zip(*(info.block(c) for c in cand))
    counts = np.asarray(counts)
    feasible = np.flatnonzero(counts >= MIN_READINGS)
    if len(feasible) < n_stations:
        raise InputError(f"only {len(feasible)} candidate position(s) see at least {MIN_READINGS} plan poses "
                         f"(line of sight, ±80° acceptance); {n_stations} stations are needed: widen the regions")

    def slot_costs(others, trial):
        base = sum(blocks[i] for i in others)
        return np.array([layout_cost(info, [base + blocks[c]], criterion) for c in trial])

    best, best_cost, evaluations = coordinate_exchange(
        cand, feasible, n_stations, lambda layout: layout_cost(info, [blocks[i] for i in layout], criterion),
        slot_costs, seed=seed, starts=starts, max_sweeps=max_sweeps, min_separation_mm=min_separation_mm,
        progress=progress, **where)
    u = info.position_u(sum(blocks[i] for i in best))
    return StationDesign(cand[best], best_cost, criterion, cand, counts, evaluations, starts, u)


def coordinate_exchange(cand, feasible, n_stations: int, layout_cost, slot_costs, *, seed: int, starts: int,
                        max_sweeps: int, min_separation_mm: float, progress=None, workers: int = 1,
                        backend: str = "loky", scheduler=None):
    """The station layout search of every design (robots and machine tools): from ``starts`` seeded random layouts
    of ``feasible`` candidates (indices into ``cand`` (C, 3) mm) pairwise ``min_separation_mm`` apart, sweeps in
    which each slot takes the candidate that lowers the cost most -- ``slot_costs(others, trial)`` (the costs of
    the layouts ``others`` + each of ``trial``, (T,)); ``layout_cost(layout)`` one layout's -- until a sweep
    improves nothing or ``max_sweeps``. Returns (best layout, its cost, layouts evaluated); ``progress(start,
    sweep, cost)`` after each sweep (as each start's search comes back). The starts are drawn here, in order, from
    one generator of ``seed``; each start's search is a trial of :func:`olti_drake.estimation.trials.run_trials`
    on ``workers`` of ``backend`` (1: in this process), so the result does not depend on where they run."""
    from olti_drake.estimation.trials import TrialTask, run_trials

    rng = np.random.default_rng(seed)
    layouts = [_random_layout(rng, cand, feasible, n_stations, min_separation_mm) for _ in range(starts)]
    if any(layout is None for layout in layouts):
        raise InputError(f"no {n_stations} feasible candidates are {min_separation_mm:g} mm apart: widen the "
                         f"regions or lower --min-separation-mm")
    search = dict(cand=cand, feasible=feasible, layout_cost=layout_cost, slot_costs=slot_costs, max_sweeps=max_sweeps,
                  min_separation_mm=min_separation_mm)

    def report(done, result):  # a start searched elsewhere: its sweeps reported as it comes back
        for sweep, cost in enumerate(result[3]) if progress and not result[4] else ():
            progress(done - 1, sweep, cost)

    # In this process the sweeps are reported as they end (``progress`` does not travel to workers).
    task = TrialTask(_search, search, _exchange_from, local=dict(search, progress=progress))
    found = run_trials(task, starts, seed, workers=workers, backend=backend, scheduler=scheduler,
                       args=list(enumerate(layouts)), progress=report)
    best, best_cost = None, np.inf
    for layout, cost, *_ in found:
        if cost < best_cost or best is None:  # (every layout inf: the caller refuses it by name)
            best, best_cost = list(layout), cost
    return best, best_cost, sum(f[2] for f in found)


def _search(search):
    return search


def _exchange_from(search, seed, start):
    """The sweeps of ``start`` = (index, layout) from its layout (drawn by :func:`coordinate_exchange`; ``seed``
    unused): (layout, cost, layouts evaluated, cost after each sweep, whether ``search['progress']`` had them)."""
    cand, feasible, min_sep = search["cand"], search["feasible"], search["min_separation_mm"]
    index, layout = start[0], list(start[1])
    live = search.get("progress")
    n_stations = len(layout)
    cost = float(search["layout_cost"](layout))
    evaluations, trace = 1, []
    for sweep in range(search["max_sweeps"]):
        improved = False
        for slot in range(n_stations):
            others = [i for k, i in enumerate(layout) if k != slot]
            near = (np.linalg.norm(cand[feasible, None] - cand[others][None], axis=2).min(axis=1) if others
                    else np.full(len(feasible), np.inf))
            trial = feasible[(near >= min_sep) & ~np.isin(feasible, layout)]
            if not trial.size:
                continue
            c = np.asarray(search["slot_costs"](others, trial), dtype=float)
            evaluations += len(trial)
            k = int(np.argmin(c))
            if c[k] < cost * (1 - 1e-9):
                cost, layout[slot], improved = float(c[k]), int(trial[k]), True
        trace.append(cost)
        if live:
            live(index, sweep, cost)
        if not improved:
            break
    return layout, cost, evaluations, trace, live is not None


def _random_layout(rng, cand, feasible, n, min_sep):
    """A seeded random set of n feasible candidates pairwise ≥ ``min_sep`` apart (None if none found)."""
    for _ in range(200):
        chosen = []
        for c in rng.permutation(feasible):
            if all(np.linalg.norm(cand[c] - cand[k]) >= min_sep for k in chosen):
                chosen.append(int(c))
                if len(chosen) == n:
                    return chosen
    return None


def evaluate_layout(info: StationInformation, stations_mm, criterion: str = "max") -> dict:
    """Cost and readings of a given layout (e.g. the result's own stations), mm."""
    blocks, counts = zip(*(info.block(s) for s in np.atleast_2d(stations_mm)))
    u = info.position_u(sum(blocks))
    return {"stations_mm": np.atleast_2d(stations_mm).tolist(), "readings": list(map(int, counts)),
            "max_u_mm": float(np.max(u)), "mean_u_mm": float(np.mean(u)),
            "cost_mm": float(np.max(u) if criterion == "max" else np.mean(u))}


def design_document(design: StationDesign, current: Optional[dict], *, budget_name: str, u_reading_mm: float,
                    result: str, plan: str, regions: str, step_mm: float, seed: int, max_sweeps: int,
                    min_separation_mm: float, workspace_poses: int, gauge: str, elapsed_s: float) -> dict:
    """The ``DESIGN.json`` document of a serial robot's station design (``olti-design/1``), mm."""
    designed = {"stations_mm": design.stations_mm.tolist(), "max_u_mm": float(np.max(design.u_mm)),
                "mean_u_mm": float(np.mean(design.u_mm)), "cost_mm": design.cost_mm}
    improvement = None
    if current is not None and np.isfinite(current["cost_mm"]) and design.cost_mm > 0:
        improvement = current["cost_mm"] / design.cost_mm
    return {"format": FORMAT, "criterion": design.criterion, "k": 1,
            "method": "linear propagation (JCGM 100): per-station information with the station's own unknowns "
                      "eliminated (Schur complement), the model's gauge, coordinate exchange from seeded starts "
                      "(olti_drake.estimation.serial_design)",
            "budget": budget_name, "u_reading_mm": u_reading_mm, "result": result, "plan": plan,
            "regions": regions, "stations_mm": designed["stations_mm"], "current": current, "designed": designed,
            "improvement": improvement, "evaluations": design.evaluations, "seed": seed, "starts": design.starts,
            "max_sweeps": max_sweeps, "gauge": gauge,
            "candidates": {"step_mm": step_mm, "count": int(len(design.candidates_mm)),
                           "feasible": int((design.readings >= MIN_READINGS).sum())},
            "rules": {"min_separation_mm": min_separation_mm, "min_readings": MIN_READINGS,
                      "line_of_sight": "serial_plan.readable: capsules about the arm, ±80° acceptance"},
            "workspace": {"poses": workspace_poses, "what": "seeded random poses in the model's commanded ranges"},
            "elapsed_s": round(elapsed_s, 3)}
