"""Where to put the stations and R-test nests of a five-axis campaign (issue 25, item 5: ``olti design`` of an
``olti-machine5/1`` result).

Given a five-axis result (its machine, its error model's location errors and linear axes) and candidate positions
-- stations on the bed (``base`` frame), stations riding on the table (``workpiece`` frame), R-test nests on the
table (``nest``, workpiece frame) -- this module chooses N of them so that the tool points' predicted uncertainty
from the rotary axes' location errors is smallest, by the linear method (JCGM 100), before any measurement:

* **Readings of a candidate**: a station reads the tool point (tool 0) at :data:`READING_POSES` seeded commands
  spread over the travel (random approach directions), r = ‖p − P‖ − L0 (001 Eq. (3)); a nest, the K4-like R-test
  path of :func:`~olti_drake.model.five_axis_plan.rtest_plan` over the widest middle share of each rotary travel
  (:data:`NEST_RANGE_SHARES`) whose path stays within the linear travel (none: no candidate), r = p − c − d
  (ISO 10791-6).
  Reading u: the budget's for distances (``--budget``; default 1 µm), 1 µm for nests
  (:data:`olti_drake.estimation.five_axis.MIXED_SIGMAS_MM`).
* **Information per candidate** (location errors, ``n`` of them): its readings' Jacobian (the result's model,
  :class:`~olti_drake.model.five_axis_errors.FiveAxisPositionModel`, analytic) with the candidate's own unknowns --
  a station's P and L0, a nest's zero -- eliminated (Schur complement). They are disjoint, so a layout's
  information is the sum of its candidates': each evaluated once.
* **Identifiable**: as the identification decides what a campaign separates
  (:func:`~olti_drake.model.five_axis_errors.separable`): while the layout's information (scaled to unit diagonal)
  has a null space, one of the location errors in it is held at 0 -- a zero angle first -- and the rest are
  identifiable (:meth:`FiveAxisDesignProblem.identifiable`).
* **Cost** (mm, k = 1): per evaluation pose (``workspace_poses`` seeded commands, tool 0, workpiece frame) u =
  sqrt(trace cov(p)) from the identifiable location errors' covariance; its maximum or mean; a layout identifying
  fewer location errors than another costs more whatever its u (:data:`UNIDENTIFIED_MM` per error left out).
* **Search**: coordinate exchange from seeded random starts
  (:func:`olti_drake.estimation.serial_design.coordinate_exchange`, every design's), candidates of one frame at
  least ``min_separation_mm`` apart.

Units: mm, deg, µrad (location errors' u as their names say).
"""

from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.propagation import predicted_variance

#: The frames a candidate region may name (``frame:`` of a region; default ``base``).
FRAMES = ("base", "workpiece", "nest")
#: Commands a station candidate reads (seeded, spread over the travel).
READING_POSES = 100
#: Poses per direction of a nest's R-test path.
NEST_STEPS = 12
#: The shares of each rotary axis' travel (about its middle, a continuous axis one turn) a nest's path sweeps: the
#: widest whose path stays within the linear travel.
NEST_RANGE_SHARES = (1.0, 0.6, 0.4, 0.25)
#: Eigenvalues of the scaled information below this share of the largest span its null space (separable's).
RANK_RTOL = 1e-8
#: A location error holding more than this of the null space is a candidate to hold (separable's share).
NULL_SHARE = 1e-3
#: What each location error a layout leaves unidentifiable adds to its cost (mm): more than any u.
UNIDENTIFIED_MM = 1e3
#: The separation test treats candidates of different frames as far apart (their coordinates are in different
#: frames): each frame's coordinates are shifted by this much (mm) for the test.
FRAME_SHIFT_MM = 1e7


@dataclass
class Candidates:
    """Candidate positions (C, 3) mm in their frames (``frame[c]``: base, workpiece or nest) and the information
    each gives on the location errors (C, n, n) -- and (C, n) the diagonal before its own unknowns were
    eliminated (what its readings see of each error at all) --, with the number of its readings."""

    positions_mm: np.ndarray
    frame: np.ndarray
    blocks: np.ndarray
    readings: np.ndarray
    raw: np.ndarray

    def information(self, layout):
        """(information (n, n), raw diagonal (n,)) of the candidates ``layout`` together."""
        layout = list(layout)
        return self.blocks[layout].sum(axis=0), self.raw[layout].sum(axis=0)

    def __len__(self) -> int:
        return len(self.frame)

    def separation_points(self) -> np.ndarray:
        """Positions shifted per frame, so that the separation rule applies within a frame only."""
        shift = np.array([FRAMES.index(f) for f in self.frame], float)[:, None] * FRAME_SHIFT_MM
        return self.positions_mm + shift * np.array([1.0, 0.0, 0.0])


@dataclass
class LayoutReport:
    """A layout's elements, costs (mm) and what it identifies: per location error its u (mm or µrad, k = 1; None
    when not identifiable)."""

    positions_mm: np.ndarray
    frame: np.ndarray
    max_u_mm: float
    mean_u_mm: float
    cost_mm: float
    location_u: Dict[str, Optional[float]]

    @property
    def identifiable(self) -> List[str]:
        return [n for n, u in self.location_u.items() if u is not None]

    def to_dict(self) -> dict:
        return {"elements": [{"kind": "nest" if f == "nest" else "station",
                              "frame": "workpiece" if f == "nest" else str(f), "position_mm": p.tolist()}
                             for p, f in zip(self.positions_mm, self.frame)],
                "max_u_mm": self.max_u_mm, "mean_u_mm": self.mean_u_mm, "cost_mm": self.cost_mm,
                "location_u": self.location_u, "identifiable": self.identifiable,
                "not_identifiable": [n for n, u in self.location_u.items() if u is None]}


@dataclass
class FiveAxisDesign:
    designed: LayoutReport
    current: Optional[LayoutReport]
    candidates: Candidates
    evaluations: int
    notes: list = field(default_factory=list)


class FiveAxisDesignProblem:
    """The location errors of a five-axis result's machine and what candidate layouts tell of them (module
    docstring). ``result``: a :class:`~olti_drake.io.five_axis_io.Machine5Result`; ``reading_std`` a callable of
    beam lengths (mm) -> distance readings' u (mm), or None for :data:`MIXED_SIGMAS_MM`'s."""

    def __init__(self, result, workspace_poses: int = 300, seed: int = 0, reading_std=None):
        from olti_drake.estimation.five_axis import MIXED_SIGMAS_MM
        from olti_drake.model.five_axis_errors import FiveAxisErrors

        self.machine = m = result.machine
        if not m.rotary:
            raise InputError(f"machine model {m.path}: no rotary axis, no location errors to design for")
        em = result.errors
        self.errors = FiveAxisErrors(m, location=True, axial=em.axial, motions=False, bidirectional=False,
                                     linear=em.linear_source(em.zeros()) if em.linear_model is None else None,
                                     tool_offsets_mm=em.tools[:1])
        self.names = self.errors.names
        self.seed, self.reading_std = int(seed), reading_std
        self.nest_sigma = MIXED_SIGMAS_MM["nest"]
        self.distance_sigma = MIXED_SIGMAS_MM["distance"]
        rng = np.random.default_rng(self.seed)
        self.commands, self.directions = self._random_commands(rng, READING_POSES)
        self._frames = {f: self._points(self.commands, self.directions, f) for f in ("base", "workpiece")}
        c, d = self._random_commands(rng, int(workspace_poses))
        _, J = self._points(c, d, "workpiece")
        self._eval = J.reshape(len(c), 3, -1)

    @property
    def tool_points_mm(self) -> np.ndarray:
        """(N, 3) the stations' reading poses' nominal tool points in the workpiece frame, mm."""
        return self._frames["workpiece"][0]

    # ------------------------------------------------------------------ readings
    def _random_commands(self, rng, n):
        """n commands uniform over (the middle 90 % of) the travel (a continuous axis: one turn), directions ±1."""
        m = self.machine
        lo, hi = (np.where(np.isfinite(v), v, s) for v, s in ((m.lower, -180.0), (m.upper, 180.0)))
        mid, half = (hi + lo) / 2, (hi - lo) / 2 * 0.9
        return rng.uniform(mid - half, mid + half, (n, len(m.axes))), rng.choice([-1.0, 1.0], (n, len(m.rotary)))

    def _points(self, commands, directions, frame):
        """(tool points (N, 3), Jacobian (3N, n) dense) in ``frame`` on the location errors at 0."""
        from olti_drake.model.five_axis_errors import FiveAxisPositionModel

        pm = FiveAxisPositionModel(self.machine, self.errors, commands, directions, frame=frame)
        p, J = pm.jacobian()
        return p, np.asarray(J.tocsr().todense())

    def station_blocks(self, positions_mm, frame: str):
        """(C, n, n) information of stations at ``positions_mm`` (C, 3) in ``frame`` (base | workpiece), their own
        P and L0 eliminated; (C,) readings (0 for a station within 1 mm of a tool point: it aims at none)."""
        p, J = self._frames[frame]
        Jp = J.reshape(len(p), 3, -1)
        P = np.atleast_2d(np.asarray(positions_mm, float))
        diff = p[None] - P[:, None]                                     # (C, N, 3)
        dist = np.linalg.norm(diff, axis=2)
        u = diff / np.maximum(dist, 1e-12)[..., None]
        sigma = (self.reading_std(dist.ravel()).reshape(dist.shape) if self.reading_std is not None
                 else np.full(dist.shape, self.distance_sigma))
        Am = np.einsum("cni,nij->cnj", u, Jp) / sigma[..., None]         # (C, N, n)
        An = np.concatenate([-u, -np.ones(dist.shape + (1,))], axis=2) / sigma[..., None]
        blocks = np.stack([_schur(a, b) for a, b in zip(Am, An)])
        ok = dist.min(axis=1) >= 1.0
        return (np.where(ok[:, None, None], blocks, 0.0), np.where(ok, len(p), 0),
                np.where(ok[:, None], np.sum(Am * Am, axis=1), 0.0))

    def nest_block(self, position_mm):
        """(n, n) information of the R-test path at a nest ``position_mm`` (workpiece frame), its zero eliminated,
        its readings and the diagonal before; (zeros, 0, zeros) when no sweep of :data:`NEST_RANGE_SHARES` stays
        within the linear travel."""
        from olti_drake.model.five_axis_plan import rtest_plan

        m, n = self.machine, len(self.names)
        for share in NEST_RANGE_SHARES:
            try:
                plan = rtest_plan(m, [position_mm], NEST_STEPS, nest_ranges(m, share))
                break
            except InputError:
                continue
        else:
            return np.zeros((n, n)), 0, np.zeros(n)
        _, J = self._points(plan.commands, plan.rotary_directions(m), "workpiece")
        A = J.reshape(len(plan), 3, n).transpose(1, 0, 2).reshape(-1, n) / self.nest_sigma  # rows x, then y, z
        zero = np.kron(np.eye(3), np.ones((len(plan), 1))) / -self.nest_sigma
        return _schur(A, zero), 3 * len(plan), np.sum(A * A, axis=0)

    def candidates(self, positions_mm, frames) -> Candidates:
        """The information of every candidate (positions (C, 3) mm, frames (C,) of :data:`FRAMES`)."""
        P, frames = np.atleast_2d(np.asarray(positions_mm, float)), np.asarray(frames, dtype=object)
        n = len(self.names)
        blocks, counts, raw = np.zeros((len(P), n, n)), np.zeros(len(P), int), np.zeros((len(P), n))
        for f in ("base", "workpiece"):
            idx = np.flatnonzero(frames == f)
            if idx.size:
                blocks[idx], counts[idx], raw[idx] = self.station_blocks(P[idx], f)
        for c in np.flatnonzero(frames == "nest"):
            blocks[c], counts[c], raw[c] = self.nest_block(P[c])
        return Candidates(P, frames, blocks, counts, raw)

    # ------------------------------------------------------------------ judging a layout
    def identifiable(self, info, raw) -> np.ndarray:
        """(n,) bool: the location errors ``info`` (n, n) separates, as the identification decides it
        (:func:`~olti_drake.model.five_axis_errors.separable`): while the null space of the scaled information
        (eigenvalues below :data:`RANK_RTOL` of the largest) is not empty, of the errors holding more than
        :data:`NULL_SHARE` of it the first of ``PREFER_DROPPING`` (a zero angle) is held, else the one holding
        most; an error no reading moves -- its information after the candidates' own unknowns below
        :data:`RANK_RTOL` of what its readings saw (``raw``: the diagonal before) -- is held first."""
        from olti_drake.model.five_axis_errors import PREFER_DROPPING

        d = np.sqrt(np.maximum(np.diag(info), 0.0))
        keep = np.diag(info) > RANK_RTOL * np.asarray(raw, float)
        while keep.any():
            idx = np.flatnonzero(keep)
            lam, V = np.linalg.eigh(info[np.ix_(idx, idx)] / np.outer(d[idx], d[idx]))
            share = np.linalg.norm(V[:, lam <= RANK_RTOL * lam[-1]], axis=1)
            inside = [i for i, s in zip(idx, share) if s > NULL_SHARE]
            if not inside:
                break
            names = [self.names[i] for i in inside]
            first = next((names.index(h) for h in PREFER_DROPPING if h in names), None)
            keep[inside[first] if first is not None else idx[int(np.argmax(share))]] = False
        return keep

    def evaluate(self, info, raw, criterion: str = "max"):
        """(cost mm, max u, mean u, per location error its u or None) of the information ``info`` (raw: its
        diagonal before the own unknowns, :meth:`identifiable`)."""
        ok = self.identifiable(info, raw)
        if not ok.any():
            return np.inf, np.inf, np.inf, {n: None for n in self.names}
        C = np.linalg.inv(info[np.ix_(ok, ok)])
        Jk = self._eval[:, :, ok]
        u = np.sqrt(predicted_variance(Jk, C).sum(axis=1))  # (the point's u: its coordinates' variances summed)
        umax, umean = float(u.max()), float(u.mean())
        cost = (umax if criterion == "max" else umean) + UNIDENTIFIED_MM * int((~ok).sum())
        std = np.sqrt(np.maximum(np.diag(C), 0.0))
        per = {n: None for n in self.names}
        per.update({n: float(s) for n, s in zip(np.asarray(self.names)[ok], std)})
        return cost, umax, umean, per

    def report(self, cand: Candidates, layout, criterion: str) -> LayoutReport:
        cost, umax, umean, per = self.evaluate(*cand.information(layout), criterion)
        return LayoutReport(cand.positions_mm[list(layout)], cand.frame[list(layout)], umax, umean, cost, per)


def nest_ranges(machine, share: float) -> Dict[str, tuple]:
    """Per rotary axis the middle ``share`` of its travel (a continuous axis: one turn), deg."""
    out = {}
    for a in machine.rotary:
        k = machine.axes.index(a)
        lo, hi = max(machine.lower[k], -180.0), min(machine.upper[k], 180.0)
        mid, half = (lo + hi) / 2, (hi - lo) / 2 * share
        out[a] = (mid - half, mid + half)
    return out


def _schur(A_model, A_own) -> np.ndarray:
    """Information on the model's columns of rows [A_model, A_own] with the own columns eliminated:
    AmᵀAm − AmᵀAo (AoᵀAo)⁺ AoᵀAm."""
    G = A_own.T @ A_model
    return A_model.T @ A_model - G.T @ np.linalg.pinv(A_own.T @ A_own) @ G


def design_layout(problem: FiveAxisDesignProblem, cand: Candidates, n: int, *, criterion: str = "max",
                  seed: int = 0, starts: int = 3, max_sweeps: int = 5, min_separation_mm: float = 100.0,
                  current: Optional[Candidates] = None, progress=None) -> FiveAxisDesign:
    """Coordinate exchange over ``cand`` for ``n`` elements (module docstring); ``current`` (the result's own
    stations) evaluated alongside."""
    from olti_drake.estimation.serial_design import coordinate_exchange
    from olti_drake.threads import single_thread_blas

    if criterion not in ("max", "mean"):
        raise InputError(f"criterion: 'max' or 'mean', not {criterion!r}")
    feasible = np.flatnonzero(cand.readings > 0)
    if len(feasible) < n:
        raise InputError(f"only {len(feasible)} of {len(cand)} candidates can be read (a nest whose R-test path "
                         f"leaves the linear travel, a station on a tool point): {n} are needed; widen the regions")

    def layout_cost(layout):
        return problem.evaluate(*cand.information(layout), criterion)[0]

    def slot_costs(others, trial):
        info, raw = cand.information(others)
        return np.array([problem.evaluate(info + cand.blocks[c], raw + cand.raw[c], criterion)[0] for c in trial])

    with single_thread_blas():  # (thousands of small n x n problems: threads only contend)
        best, _, evaluations = coordinate_exchange(cand.separation_points(), feasible, n, layout_cost, slot_costs,
                                                   seed=seed, starts=starts, max_sweeps=max_sweeps,
                                                   min_separation_mm=min_separation_mm, progress=progress)
        designed = problem.report(cand, best, criterion)
        now = problem.report(current, range(len(current)), criterion) if current is not None and len(current) else None
    unread = len(cand) - len(feasible)
    notes = [f"{unread} of {len(cand)} candidates read nothing (a nest whose R-test path leaves the linear travel at "
             f"every sweep share, a station on a tool point): not used"] if unread else []
    return FiveAxisDesign(designed, now, cand, evaluations, notes)


def region_frames(path, n_boxes: int) -> List[str]:
    """The ``frame:`` of every region of a regions YAML (base, workpiece or nest; default base), one-line errors."""
    from olti_drake.io.csvio import read_yaml

    regions = read_yaml(path, "a regions file").get("regions", [])
    out = []
    for i, reg in enumerate(regions[:n_boxes]):
        f = reg.get("frame", "base") if isinstance(reg, dict) else "base"
        if f not in FRAMES:
            raise InputError(f"{path}: regions[{i}].frame = {f!r}: a five-axis design takes base (stations on the "
                             f"bed), workpiece (stations riding on the table) or nest (R-test nests on the table)")
        out.append(str(f))
    return out


def design_document(design: FiveAxisDesign, *, result: str, regions: str, step_mm: float, criterion: str,
                    seed: int, starts: int, max_sweeps: int, min_separation_mm: float, workspace_poses: int,
                    budget: str, elapsed_s: float) -> dict:
    """The ``olti-design/1`` document of a five-axis layout design (mm; u k = 1)."""
    from olti_drake.formats import DESIGN

    d, cur = design.designed, design.current
    cand = design.candidates
    return {"format": DESIGN, "kind": "machine5", "criterion": criterion, "k": 1,
            "method": "linear propagation (JCGM 100) of the location errors' information: per candidate its "
                      "readings' Jacobian with its own unknowns eliminated (Schur complement), identifiability by "
                      "the rank of the layout's information, coordinate exchange from seeded starts "
                      "(olti_drake.estimation.five_axis_design)",
            "result": result, "regions": regions, "budget": budget,
            "designed": d.to_dict(), "current": cur.to_dict() if cur is not None else None,
            "improvement": (cur.cost_mm / d.cost_mm if cur is not None and np.isfinite(cur.cost_mm)
                            and d.cost_mm > 0 else None),
            "evaluations": design.evaluations, "seed": seed, "starts": starts, "max_sweeps": max_sweeps,
            "candidates": {"step_mm": step_mm, "count": len(cand),
                           "by_frame": {f: int(np.sum(cand.frame == f)) for f in FRAMES},
                           "readable": int(np.sum(cand.readings > 0))},
            "readings": {"station_poses": READING_POSES, "nest_steps": NEST_STEPS,
                         "nest_range_shares": list(NEST_RANGE_SHARES)},
            "rules": {"min_separation_mm": min_separation_mm, "rank_rtol": RANK_RTOL, "null_share": NULL_SHARE,
                      "unidentified_mm": UNIDENTIFIED_MM},
            "workspace": {"poses": workspace_poses, "what": "seeded random commands over the travel, tool 0, "
                                                            "workpiece frame"},
            "notes": list(design.notes), "elapsed_s": round(elapsed_s, 3)}
