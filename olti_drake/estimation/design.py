"""Reflector (station) placement design by the linear uncertainty method (000 §3.2.2 Remark 2, §5).

000 §3.2.2 Remark 2: the uncertainty of the open-loop tracking measurement
depends strongly on where the retroreflectors stand -- the paper's three
positions lie almost on a line, so the end effector is poorly located near
that line -- and "the uncertainty analysis (§5) is essential for the design
of retroreflector positions". This module does that design:

* :func:`layout_cost` -- the worst (or mean) standard uncertainty (k = 1) of
  the predicted end-effector position, sqrt(u_x² + u_y²) in mm, over a set of
  workspace commands, for a campaign that runs the plan against the given
  reflectors. The campaign is synthesized with the model as the truth (its
  own distances as readings, the counter zeroed at each reflector's first
  reading), the identification problem is the package's own
  :class:`~olti_drake.estimation.identification.Identifier` (same map grids, reflectors
  and dead paths unknown, same gauge) and the uncertainty is
  :func:`~olti_drake.estimation.uncertainty.linear_covariance` (JCGM 100, the budget of
  000 Table 2) followed by :func:`~olti_drake.estimation.uncertainty.prediction_std`.
* :func:`design_layout` -- coordinate exchange over candidate positions:
  from several seeded random starts, replace one reflector at a time by the
  candidate that lowers the cost most, until a whole sweep brings nothing.
* :func:`candidate_grid`, :func:`load_regions` -- candidates on a grid inside
  rectangles of the floor (YAML, e.g. ``data/regions_paper000.yaml``).
* :func:`workspace_commands` -- where the cost is evaluated: an XY grid of the
  reachable workspace inside the map range, both approach directions.

Candidate rules (parameters of :func:`design_layout`): a reflector keeps
``clearance_mm`` from every measured and workspace end-effector position (it
must not stand in the arm's way), reflectors keep ``min_separation_mm`` from
each other, and no beam from a measured pose to a reflector passes closer
than ``base_radius_mm`` to the J1 axis (a 2D model of the robot's base column
blocking the beam). Layouts the identification cannot determine
(:class:`~olti_drake.estimation.identification.UnidentifiableError`) cost infinity.
(With the kinematic model's constraints even coincident reflectors are
locally identifiable, at a higher cost; the separation rule keeps them apart.)

Units: mm and degrees; uncertainties standard (k = 1) unless said otherwise.
"""

import os
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Sequence, Tuple, Union

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import DESIGN as FORMAT
from olti_drake.io.csvio import CampaignData
from olti_drake.io.csvio import read_yaml
from olti_drake.estimation.identification import UnidentifiableError
from olti_drake.model.budget import Budget
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM, JointCommands, ScaraModel, workspace_grid
from olti_drake.model.plan import Plan
from olti_drake.threads import single_thread_blas
from olti_drake.units import unit_bound

#: Default minimum distance between two reflectors, mm.
MIN_SEPARATION_MM = 100.0
#: Default minimum distance of a reflector from every measured/workspace end-effector position, mm.
CLEARANCE_MM = 50.0
#: Default radius about the J1 axis that a beam must not cross (the robot's base column, 2D), mm.
BASE_RADIUS_MM = 40.0
#: Default step of the workspace XY grid on which the cost is evaluated, mm.
WORKSPACE_STEP_MM = 50.0
CRITERIA = ("max", "mean")


# -- regions and candidates ----------------------------------------------------------------------
@dataclass(frozen=True)
class Region:
    """A rectangle of the floor where reflectors may stand: x and y ranges [lo, hi], mm."""

    x_mm: Tuple[float, float]
    y_mm: Tuple[float, float]
    name: str = ""


_REGION_KEYS = ("x_mm", "y_mm", "name")


def parse_regions(data, where: str = "regions") -> List[Region]:
    """Regions from parsed YAML: a list of ``{x_mm: [lo, hi], y_mm: [lo, hi], name: ...}`` or a
    mapping with that list under ``regions``. One-line InputError naming the field.
    """
    if isinstance(data, dict):
        extra = sorted(set(data) - {"regions"})
        if extra:
            raise InputError(f"{where}: unknown key '{extra[0]}' (expected 'regions')")
        if "regions" not in data:
            raise InputError(f"{where}: missing key 'regions'")
        data, where = data["regions"], f"{where}: regions"
    if not isinstance(data, list) or not data:
        raise InputError(f"{where}: expected a non-empty list of rectangles "
                         f"{{x_mm: [lo, hi], y_mm: [lo, hi]}}, got {type(data).__name__}")
    out = []
    for i, item in enumerate(data):
        label = f"{where}[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{label}: expected a mapping {{x_mm: [lo, hi], y_mm: [lo, hi]}}, "
                             f"got {type(item).__name__}")
        extra = sorted(set(item) - set(_REGION_KEYS))
        if extra:
            raise InputError(f"{label}: unknown key '{extra[0]}' (expected x_mm, y_mm, name)")
        ranges = []
        for key in ("x_mm", "y_mm"):
            if key not in item:
                raise InputError(f"{label}: missing key '{key}'")
            v = item[key]
            try:
                lo, hi = (float(a) for a in v)
                if (isinstance(v, (str, bytes)) or not np.all(np.abs([lo, hi]) <= unit_bound(key)) or lo > hi):
                    raise ValueError
            except (TypeError, ValueError):
                raise InputError(f"{label}.{key}: expected [lo, hi] in mm, finite, within +-{unit_bound(key):g} mm, "
                                 f"lo <= hi, got {v!r}") from None
            ranges.append((lo, hi))
        name = item.get("name", "")
        out.append(Region(ranges[0], ranges[1], str(name) if name is not None else ""))
    return out


def load_regions(path) -> List[Region]:
    """Load a regions YAML (see :func:`parse_regions`); errors name the file and the field (duplicate keys
    and non-UTF-8 bytes by line: :func:`~olti_drake.io.csvio.read_yaml`)."""
    return parse_regions(read_yaml(path, "regions"), os.fspath(path))


#: Most candidate positions: the coordinate exchange evaluates every candidate for every reflector in
#: every sweep; a finer step is a slip (that would also allocate gigabytes), refused before allocating.
MAX_CANDIDATES = 100_000


def candidate_grid(regions: Sequence[Region], step_mm: float, option: str = "step_mm") -> np.ndarray:
    """Candidate reflector positions (C, 2) mm on a square grid of ``step_mm`` inside the rectangles.

    Each rectangle gets floor(span/step) + 1 points per axis, centred in it (a
    zero-width range gives one line of points); points shared by overlapping
    rectangles appear once. Order: by rectangle, then x, then y. At most
    :data:`MAX_CANDIDATES` points; errors name ``option`` (the step's parameter).
    """
    if not (np.isfinite(step_mm) and step_mm > 0):
        raise InputError(f"{option} must be finite and > 0, got {step_mm!r}")
    count = sum((np.floor((r.x_mm[1] - r.x_mm[0]) / step_mm) + 1) * (np.floor((r.y_mm[1] - r.y_mm[0]) / step_mm) + 1)
                for r in regions)
    if count > MAX_CANDIDATES:
        raise InputError(f"{option} {step_mm:g} mm gives {count:.3g} candidate positions in the regions, more than "
                         f"{MAX_CANDIDATES:,} (use a coarser step)")
    pts = []
    for r in regions:
        axes = []
        for lo, hi in (r.x_mm, r.y_mm):
            n = int(np.floor((hi - lo) / step_mm + 1e-9)) + 1
            axes.append(lo + (hi - lo - (n - 1) * step_mm) / 2 + step_mm * np.arange(n))
        gx, gy = np.meshgrid(*axes, indexing="ij")
        pts.append(np.column_stack([gx.ravel(), gy.ravel()]))
    P = np.vstack(pts)
    _, first = np.unique(np.round(P, 6), axis=0, return_index=True)
    return P[np.sort(first)]


# -- commands -------------------------------------------------------------------------------------
def measured_commands(plan_or_commands: Union[Plan, JointCommands]) -> JointCommands:
    """The measured poses of a plan (angles deg, directions ±1), or the commands themselves."""
    if isinstance(plan_or_commands, Plan):
        m = plan_or_commands.measured()
        return JointCommands(m.theta1_deg, m.theta2_deg, m.dir1, m.dir2)
    if isinstance(plan_or_commands, JointCommands):
        return plan_or_commands
    raise InputError(f"expected a Plan or JointCommands, got {type(plan_or_commands).__name__}")


def workspace_commands(model_or_grids, step_mm: float = WORKSPACE_STEP_MM, L1_mm: Optional[float] = None,
                       L2_mm: Optional[float] = None, option: str = "step_mm") -> JointCommands:
    """Commands reaching an XY grid (step ``step_mm``, mm) of the workspace inside the map range.

    ``model_or_grids``: an error-map :class:`ScaraModel` (its grids give the
    J1, J2 ranges, its link lengths the inverse kinematics) or a pair
    ``(grid1_deg, grid2_deg)`` of which only the ranges count (link lengths
    ``L1_mm``, ``L2_mm``, default the paper's 325/225 mm). Every grid point
    (x, y) whose nominal inverse kinematics (either elbow) lies in both ranges
    gives four commands: approach directions (dir1, dir2) = (+1, +1), (+1, −1),
    (−1, +1), (−1, −1) -- the bidirectional map (000 Eq. 7) differs by
    direction. Order: by point, then direction. Errors name ``option`` (the step's parameter).
    """
    if isinstance(model_or_grids, ScaraModel):
        if not model_or_grids.is_errormap:
            raise InputError("workspace_commands: a D-H model has no map range; pass (grid1_deg, grid2_deg), "
                             "e.g. the plan's angle ranges")
        g1, g2 = model_or_grids.map1.grid_deg, model_or_grids.map2.grid_deg
        L1 = model_or_grids.L1_mm if L1_mm is None else L1_mm
        L2 = model_or_grids.L2_mm if L2_mm is None else L2_mm
    else:
        try:
            g1, g2 = (np.asarray(g, dtype=float).ravel() for g in model_or_grids)
        except (TypeError, ValueError):
            raise InputError("workspace_commands: expected a ScaraModel or (grid1_deg, grid2_deg)") from None
        L1 = PAPER_L1_MM if L1_mm is None else L1_mm
        L2 = PAPER_L2_MM if L2_mm is None else L2_mm
    try:
        _, _, t1, t2 = workspace_grid(L1, L2, g1, g2, step_mm, option)
    except ValueError as e:
        raise InputError(str(e)) from None
    if not t1.size:
        raise InputError(f"workspace_commands: no point of the {step_mm:g} mm grid lies inside the map range "
                         f"J1 [{g1.min():g}, {g1.max():g}] deg, J2 [{g2.min():g}, {g2.max():g}] deg")
    d1 = np.tile([1.0, 1.0, -1.0, -1.0], t1.size)
    d2 = np.tile([1.0, -1.0, 1.0, -1.0], t1.size)
    return JointCommands(np.repeat(t1, 4), np.repeat(t2, 4), d1, d2)


# -- the cost ---------------------------------------------------------------------------------------
def synthetic_campaign(model: ScaraModel, commands: JointCommands, reflectors_mm,
                       source: str = "synthetic campaign (plan row)") -> Tuple[CampaignData, np.ndarray]:
    """The campaign of ``commands`` run once per reflector with ``model`` as the truth, noise-free.

    Readings d_j(k) = ‖p(k) − P_j‖ − d0_j, d0_j the distance at reflector j's
    first reading (the counter is zeroed there), 000 Eq. (10). Returns the
    CampaignData (lines = 1-based command index) and the dead paths d0 (Nt,) mm.
    """
    P = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)
    p = model.positions(commands)
    n_t, k = len(P), len(commands)
    dist = np.hypot(p[None, :, 0] - P[:, None, 0], p[None, :, 1] - P[:, None, 1])  # (Nt, K)
    d0 = dist[:, 0].copy()
    c = commands
    cmd = JointCommands(np.tile(c.theta1_deg, n_t), np.tile(c.theta2_deg, n_t), np.tile(c.dir1, n_t),
                        np.tile(c.dir2, n_t))
    data = CampaignData(np.repeat(np.arange(n_t), k), cmd, (dist - d0[:, None]).ravel(),
                        np.tile(np.arange(1, k + 1), n_t), source)
    return data, d0


class LayoutEvaluator:
    """Predicted-position uncertainty of candidate layouts for one model, plan, reflector count.

    The identification problem does not depend on where the reflectors are
    (names, map grids, gauge): one :class:`Identifier` is built for the first
    layout and copied, with that layout's synthetic campaign and its truth as
    the start, for every other -- the expensive program set-up runs once.
    """

    def __init__(self, model: ScaraModel, plan_or_commands, n_reflectors: int, workspace: JointCommands):
        self.model = model
        self.commands = measured_commands(plan_or_commands)
        self.n_reflectors = int(n_reflectors)
        self.workspace = workspace
        self._template = None
        self.evaluations = 0

    def identifier(self, reflectors_mm):
        """(Identifier, truth x) of the synthetic campaign against these reflectors (Nt, 2) mm."""
        import copy

        from olti_drake.estimation.identification import IdentificationOptions, Identifier

        P = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)
        if len(P) != self.n_reflectors:
            raise InputError(f"expected {self.n_reflectors} reflector positions, got {len(P)}")
        if not np.all(np.isfinite(P)):
            raise InputError("reflector positions must be finite")
        data, d0 = synthetic_campaign(self.model, self.commands, P)
        x = np.concatenate([self.model.parameter_vector(), P.ravel(), d0])
        if self._template is None:
            m = self.model
            opts = IdentificationOptions(model="errormap" if m.is_errormap else "dh", nominal_L1_mm=m.L1_mm,
                                         nominal_L2_mm=m.L2_mm)
            if m.is_errormap:
                opts.grid1_deg, opts.grid2_deg = m.map1.grid_deg, m.map2.grid_deg
            self._template = Identifier(data, opts)
            ident = self._template
        else:
            ident = copy.copy(self._template)
            ident.data = data
            ident.notes = []
        ident.x0 = x  # the start is the truth
        return ident, x

    def position_std(self, reflectors_mm, budget) -> np.ndarray:
        """sqrt(u_x² + u_y²) (W,) mm, k = 1, at every workspace command.

        Raises UnidentifiableError when the campaign cannot determine the parameters.
        """
        from olti_drake.estimation.uncertainty import linear_covariance, prediction_std
        from olti_drake.model.budget import ReadingErrors

        errors = budget if isinstance(budget, ReadingErrors) else ReadingErrors(budget)
        ident, x = self.identifier(reflectors_mm)
        self.evaluations += 1
        with single_thread_blas():
            ident.check_identifiability(x)
            cov = linear_covariance(ident, x, errors)
            return np.hypot(*prediction_std(ident, cov, x, self.workspace).T)

    def cost(self, reflectors_mm, budget, criterion: str = "max") -> float:
        """Worst (``max``) or mean (``mean``) predicted-position u (k = 1) over the workspace, mm."""
        u = self.position_std(reflectors_mm, budget)
        return float(u.max() if criterion == "max" else u.mean())


_EVALUATORS: list = []


def _evaluator(model, plan_or_commands, n_reflectors, workspace) -> LayoutEvaluator:
    """A cached :class:`LayoutEvaluator` for these very objects (identity), so repeated calls are fast."""
    for e, key in _EVALUATORS:
        if key[0] is model and key[1] is plan_or_commands and key[2] == n_reflectors and key[3] is workspace:
            return e
    e = LayoutEvaluator(model, plan_or_commands, n_reflectors, workspace)
    _EVALUATORS.insert(0, (e, (model, plan_or_commands, n_reflectors, workspace)))
    del _EVALUATORS[4:]
    return e


def _check_criterion(criterion):
    if criterion not in CRITERIA:
        raise InputError(f"criterion must be 'max' or 'mean', got {criterion!r}")


def layout_cost(model: ScaraModel, plan_or_commands, reflectors_mm, budget: Budget,
                workspace_commands: JointCommands, criterion: str = "max") -> float:
    """Cost of a reflector layout (000 §3.2.2 Remark 2, §5): the worst or mean predicted-position
    standard uncertainty sqrt(u_x² + u_y²) (k = 1, mm) over ``workspace_commands``.

    The campaign runs the plan's measured poses (or the given commands)
    against ``reflectors_mm`` (Nt, 2) mm with ``model`` as the truth; the
    identification (error map on the model's grids, or D-H) is propagated by
    the linear method with the ``budget`` (000 Table 2). Repeated calls with
    the same model, plan and workspace objects reuse the identification set-up.

    Raises UnidentifiableError when the layout cannot determine the
    parameters (fewer than 3 reflectors, or readings that leave a parameter
    combination undetermined).
    """
    _check_criterion(criterion)
    P = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)
    return _evaluator(model, plan_or_commands, len(P), workspace_commands).cost(P, budget, criterion)


# -- the design --------------------------------------------------------------------------------------
@dataclass
class DesignResult:
    """A designed layout: positions (Nt, 2) mm, its cost (mm, k = 1) and how it was found.

    ``history``: per start, the cost at the random start and after every
    sweep. ``evaluations``: layouts whose cost was computed (repeats are
    looked up). ``candidates_mm`` / ``feasible``: the distinct candidates and
    which passed the clearance and beam rules; ``index``: the chosen ones.
    """

    reflectors_mm: np.ndarray
    cost: float
    criterion: str
    history: List[List[float]]
    evaluations: int
    index: np.ndarray
    candidates_mm: np.ndarray
    feasible: np.ndarray
    start_costs: List[float] = field(default_factory=list)
    seed: int = 0
    rejected: dict = field(default_factory=dict)


def beam_axis_distance(positions_mm, reflectors_mm) -> np.ndarray:
    """Closest approach (C,) mm to the J1 axis of the beams from the positions (K, 2) to each reflector."""
    return beam_axis_distances(positions_mm, reflectors_mm).min(axis=1)


def beam_axis_distances(positions_mm, reflectors_mm) -> np.ndarray:
    """Closest approach (C, K) mm to the J1 axis (the origin) of the beam from each position (K, 2) to each
    reflector (C, 2): the segment from the end effector to the reflector (2D)."""
    p = np.asarray(positions_mm, dtype=float)[None]  # (1, K, 2)
    P = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)[:, None]  # (C, 1, 2)
    d = P - p
    t = np.clip(-np.sum(p * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-300), 0.0, 1.0)
    q = p + t[..., None] * d
    return np.hypot(q[..., 0], q[..., 1])


def feasible_candidates(model: ScaraModel, plan_or_commands, candidates_mm, workspace: JointCommands,
                        clearance_mm: float = CLEARANCE_MM, base_radius_mm: float = BASE_RADIUS_MM):
    """(mask (C,), counts of rejections by rule) for candidate reflector positions (C, 2) mm.

    Rejected: closer than ``clearance_mm`` to any measured or workspace
    end-effector position (the reflector would stand in the arm's way), or a
    beam from a measured pose passing within ``base_radius_mm`` of the J1 axis.
    """
    C = np.asarray(candidates_mm, dtype=float).reshape(-1, 2)
    measured = model.positions(measured_commands(plan_or_commands))
    arm = np.vstack([measured, model.positions(workspace)])
    gap = np.full(len(C), np.inf)
    for a in np.array_split(arm, max(1, len(arm) // 2000)):
        gap = np.minimum(gap, np.min(np.hypot(C[:, None, 0] - a[None, :, 0], C[:, None, 1] - a[None, :, 1]),
                                     axis=1))
    near = gap < clearance_mm
    blocked = (beam_axis_distance(measured, C) < base_radius_mm) & ~near if base_radius_mm > 0 else \
        np.zeros(len(C), bool)
    return ~(near | blocked), {"clearance": int(near.sum()), "base": int(blocked.sum())}


def design_layout(model: ScaraModel, plan, candidates_mm, n_reflectors: int, budget: Budget,
                  workspace_commands: JointCommands, criterion: str = "max", seed: int = 0, starts: int = 3,
                  max_sweeps: int = 5, min_separation_mm: float = MIN_SEPARATION_MM,
                  clearance_mm: float = CLEARANCE_MM, base_radius_mm: float = BASE_RADIUS_MM,
                  evaluator: Optional[LayoutEvaluator] = None,
                  progress: Optional[Callable[[int, int, float], None]] = None) -> DesignResult:
    """Reflector positions minimizing :func:`layout_cost` by coordinate exchange (000 §3.2.2 Remark 2).

    From ``starts`` random layouts (seeded by ``seed``; distinct feasible
    candidates at least ``min_separation_mm`` apart), each sweep replaces
    reflector 0, 1, ... in turn by the feasible candidate that lowers the cost
    most (keeping the separation); stops when a sweep improves nothing or
    after ``max_sweeps``. The best layout of all starts wins. Layouts the
    identification cannot determine cost infinity.

    Args:
        model: the truth (an identified result's model), mm/deg.
        plan: the measurement plan (or its measured commands).
        candidates_mm: (C, 2) candidate positions, mm (duplicates ignored).
        n_reflectors: reflectors to place (>= 3, 000 §3.2.2 Remark 1).
        budget: reading uncertainty budget (000 Table 2).
        workspace_commands: where the cost is evaluated (:func:`workspace_commands`).
        criterion: ``max`` or ``mean`` over the workspace.
        evaluator: a :class:`LayoutEvaluator` to reuse (same model, plan, n_reflectors, workspace).
        progress: called as ``progress(start, sweep, cost_mm)`` after every sweep (0-based).

    Raises InputError when the candidates cannot hold the layout (too few
    feasible or separated candidates) or no identifiable layout was found.
    """
    _check_criterion(criterion)
    n = int(n_reflectors)
    if n < 3:
        raise InputError(f"n_reflectors must be >= 3 (reflector positions unknown: 000 §3.2.2 Remark 1), got {n}")
    for name, v in (("starts", starts), ("max_sweeps", max_sweeps)):
        if int(v) < 1:
            raise InputError(f"{name} must be >= 1, got {v}")
    for name, v in (("min_separation_mm", min_separation_mm), ("clearance_mm", clearance_mm),
                    ("base_radius_mm", base_radius_mm)):
        if not (np.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be finite and >= 0, got {v!r}")
    C = np.asarray(candidates_mm, dtype=float)
    if C.ndim != 2 or C.shape[1] != 2 or not len(C) or not np.all(np.isfinite(C)):
        raise InputError(f"candidates_mm must be a non-empty (C, 2) array of finite positions, got shape {C.shape}")
    _, first = np.unique(np.round(C, 6), axis=0, return_index=True)
    C = C[np.sort(first)]
    if len(C) < n:
        raise InputError(f"the candidates hold only {len(C)} distinct position(s); {n} reflectors need {n}")
    ev = evaluator or LayoutEvaluator(model, plan, n, workspace_commands)
    feasible, rejected = feasible_candidates(model, plan, C, workspace_commands, clearance_mm, base_radius_mm)
    ok = np.flatnonzero(feasible)
    if len(ok) < n:
        raise InputError(f"only {len(ok)} of {len(C)} candidate position(s) are feasible ({rejected['clearance']} "
                         f"within {clearance_mm:g} mm of the arm, {rejected['base']} with a beam within "
                         f"{base_radius_mm:g} mm of the J1 axis); {n} reflectors need {n}")
    sep = np.hypot(C[:, None, 0] - C[None, :, 0], C[:, None, 1] - C[None, :, 1]) >= min_separation_mm
    np.fill_diagonal(sep, False)
    rng = np.random.default_rng(seed)
    memo = {}
    evals0 = ev.evaluations

    def cost(idx):
        key = tuple(sorted(idx))
        if key not in memo:
            try:
                memo[key] = ev.cost(C[list(idx)], budget, criterion)
            except (UnidentifiableError, np.linalg.LinAlgError):
                memo[key] = np.inf
        return memo[key]

    def random_start():
        for _ in range(100):
            idx = []
            for _ in range(n):
                allowed = ok[np.all(sep[np.ix_(ok, idx)], axis=1)] if idx else ok
                allowed = np.setdiff1d(allowed, idx)
                if not len(allowed):
                    break
                idx.append(int(rng.choice(allowed)))
            if len(idx) == n:
                return idx
        raise InputError(f"cannot place {n} reflectors at least {min_separation_mm:g} mm apart among the "
                         f"{len(ok)} feasible candidate position(s)")

    best_idx, best_cost, history, start_costs = None, np.inf, [], []
    for _ in range(int(starts)):
        idx = random_start()
        c = cost(idx)
        trace = [c]
        start_costs.append(c)
        for _ in range(int(max_sweeps)):
            improved = False
            for i in range(n):
                others = idx[:i] + idx[i + 1:]
                allowed = ok[np.all(sep[np.ix_(ok, others)], axis=1)]
                allowed = np.setdiff1d(allowed, others)
                if not len(allowed):
                    continue
                costs = np.array([cost(others[:i] + [int(a)] + others[i:]) for a in allowed])
                k = int(np.argmin(costs))
                if costs[k] < c * (1 - 1e-12) or (np.isinf(c) and np.isfinite(costs[k])):
                    idx[i], c, improved = int(allowed[k]), float(costs[k]), True
            trace.append(c)
            if progress:
                progress(len(history), len(trace) - 2, c)
            if not improved:
                break
        history.append(trace)
        if c < best_cost:
            best_idx, best_cost = list(idx), c
    if best_idx is None or not np.isfinite(best_cost):
        raise InputError(f"no identifiable layout of {n} reflectors among the {len(ok)} feasible candidate "
                         f"position(s) (every layout tried leaves parameters undetermined)")
    order = np.array(best_idx)
    return DesignResult(C[order], float(best_cost), criterion, history, ev.evaluations - evals0, order, C, feasible,
                        start_costs, int(seed), rejected)


# -- the design document (DESIGN.json; FORMAT: olti_drake.formats.DESIGN) ------------------------------------


def layout_costs(u) -> dict:
    """The costs of one layout from its predicted-position u over the workspace (mm, k = 1; U = 2u)."""
    return {"max_u_mm": float(u.max()), "mean_u_mm": float(u.mean()), "max_U_k2_mm": float(2 * u.max()),
            "mean_U_k2_mm": float(2 * u.mean())}


def evaluate_layout(evaluator: LayoutEvaluator, reflectors_mm, budget: Budget) -> dict:
    """``{"reflectors_mm", costs}`` of a layout, or ``{"reflectors_mm", "not_identifiable": why}`` (one line)."""
    from olti_drake.estimation.identification import UnidentifiableError

    out = {"reflectors_mm": np.asarray(reflectors_mm, dtype=float).tolist()}
    try:
        out.update(layout_costs(evaluator.position_std(np.asarray(reflectors_mm, dtype=float), budget)))
    except UnidentifiableError as e:
        out["not_identifiable"] = " ".join(str(e).split())
    return out


@dataclass
class DesignReport:
    """A layout design compared with the current layout: what ``olti design`` prints and writes (mm, k = 1).

    ``current`` / ``designed``: :func:`evaluate_layout` dicts; ``design``: the :class:`DesignResult`;
    the rest says where the inputs came from and the search settings, so the document is reproducible.
    """

    criterion: str
    budget: Budget
    budget_file: str
    result: str
    plan: str
    regions: str
    current: dict
    designed: dict
    design: "DesignResult"
    seed: int
    starts: int
    max_sweeps: int
    step_mm: float
    rules: dict
    workspace_step_mm: float
    workspace_commands: int
    elapsed_s: float

    @property
    def improvement(self) -> Optional[float]:
        """Current / designed cost of the criterion; None when the current layout is not identifiable."""
        key = f"{self.criterion}_u_mm"
        return self.current[key] / self.designed[key] if key in self.current else None

    def to_dict(self) -> dict:
        """The ``DESIGN.json`` document (format ``olti-design/1``)."""
        res = self.design
        return {"format": FORMAT, "criterion": self.criterion, "k": 1,
                "method": "linear propagation (JCGM 100) of the identification (000 §5 Remark); coordinate "
                          "exchange over candidate positions from seeded random starts",
                "budget": self.budget.name, "budget_file": self.budget_file,
                "result": self.result, "plan": self.plan, "regions": self.regions,
                "reflectors_mm": self.designed["reflectors_mm"], "current": self.current, "designed": self.designed,
                "improvement": self.improvement, "evaluations": res.evaluations, "seed": self.seed,
                "starts": self.starts, "max_sweeps": self.max_sweeps, "cost_history_mm": res.history,
                "candidates": {"step_mm": self.step_mm, "count": int(len(res.candidates_mm)),
                               "feasible": int(res.feasible.sum()), "rejected": res.rejected},
                "rules": dict(self.rules),
                "workspace": {"step_mm": self.workspace_step_mm, "commands": self.workspace_commands,
                              "directions": "(dir1, dir2) = (+1, +1), (+1, -1), (-1, +1), (-1, -1)"},
                "elapsed_s": round(self.elapsed_s, 3)}
