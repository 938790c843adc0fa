"""Station layout design in 3D for the machine tool's multilateration (issue 15 item 2; 001 §4.4 in 3D).

Where the pan/tilt heads stand decides how well the self-calibrating multilateration (001 Eq. (2)-(6)
with p_i, P_j ∈ ℝ³) locates the targets. Given a result -- a 3D ``olti-multilateration/1`` (its targets,
the gauge it was solved in) or an ``olti-volumetric/1`` (the identified tool points on a grid of the travel,
every tool) -- this module chooses N stations among candidates in 3D boxes so that the worst (or mean)
target uncertainty is smallest, by the linear method (JCGM 100) of the budget (001 Table 4 by default),
before any measurement:

* **Information per station** (:mod:`olti_drake.estimation.station_information`): a head at P reads every
  target, d_i = ‖p_i − P‖ − L0 (001 Eq. (3)); its own unknowns (P, L0) are projected out, and because the
  multilateration is an *unweighted* least squares while the budget's reading uncertainty grows with the
  distance, each station contributes the two additive parts of the sandwich covariance (S₀, M): a layout's
  are their sums, each candidate evaluated once -- the same mechanism as the serial robot's design
  (:mod:`olti_drake.estimation.serial_design`), whose coordinate exchange runs it here too.
* **Gauge**: the result's 3D gauge (6 freedoms; ``best-fit`` or ``first-three``,
  :func:`olti_drake.estimation.multilateration._gauge_rows` on the nominal target positions), so a
  layout's target covariance is the full problem's (``olti uncertainty``, linear) for that layout.
* **Evaluation** (:class:`LayoutCosts`, issue 24 class 5): the same covariance from the structure of the
  multilateration (3 × 3 blocks per target, a (4 N_j + 6)² system per layout) instead of the dense
  (3 N_i)² sandwich, a whole slot's candidates at once: ~1 ms instead of ~1 s per layout for 360 targets.
  Without ``--step-mm`` the candidate step comes from the regions' size (:func:`default_step_mm`); a design
  whose estimated run time exceeds :data:`MAX_DESIGN_SECONDS` is refused before any work
  (:func:`check_design_time`).
* **Cost**: u_i = sqrt(trace cov(p_i)) (mm, k = 1) per target; its maximum or mean. A layout the
  multilateration cannot solve costs infinity; the candidates are refused up front by name when every
  layout would be degenerate: all candidates in one plane (coplanar stations trade a target's offset
  across the plane against the dead paths), too few targets for N stations (the counting condition
  N_i > (4 N_j − 6)/(N_j − 3), 001 Eq. (4) in 3D), fewer than 4 stations, targets in one plane.

Units: mm; uncertainties standard (k = 1).
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.formats import DESIGN as FORMAT
from olti_drake.estimation.multilateration import _gauge_rows, affine_rank, counting_bound, load_result
from olti_drake.estimation.station_information import Sandwich, predicted_u, station_sandwich
from olti_drake.io.documents import read_result
from olti_drake.model.budget import ReadingErrors
from olti_drake.model.volumetric3d import AXES

#: A candidate closer than this to a target cannot aim at it (the beam direction is undefined), mm.
MIN_RANGE_MM = 1.0
#: Grid points per axis of a volumetric result's travel where the targets are placed.
VOLUMETRIC_GRID = 3


@dataclass
class DesignTargets:
    """The targets the cost is taken over: positions (N, 3) mm (where the heads aim), their nominal
    positions (commands + tool offsets, mm: the gauge is stated on these), the gauge kind, the current
    stations (or None) and a sentence saying where they came from."""

    targets_mm: np.ndarray
    nominal_mm: np.ndarray
    gauge_kind: str
    stations_mm: object
    what: str


def design_targets(path) -> DesignTargets:
    """The targets of a 3D multilateration result or of a volumetric result (module docstring); one-line
    errors naming the file for anything else (a 2D result, a SCARA result)."""
    kind, _ = read_result(path, ("multilateration", "volumetric"), "the station design of a 3D machine tool")
    name = str(path)
    if kind == "volumetric":
        return _volumetric_targets(path)
    raw = load_result(path)
    T = np.asarray(raw["targets_mm"], float)
    if T.shape[1] != 3:
        raise InputError(f"{name}: a 2D machine-tool result: the station design here places heads in 3D (give "
                         f"the result of olti multilaterate on a 3D campaign)")
    nominal = np.asarray(raw.get("commands_mm", T), float)
    if "tool_offsets_mm" in raw:
        nominal = nominal + np.asarray(raw["tool_offsets_mm"], float)[np.asarray(raw["tools"])]
    return DesignTargets(T, nominal, raw["gauge_kind"], np.asarray(raw["stations_mm"], float),
                         f"the {len(T)} targets of {name} ({raw['gauge_kind']} gauge)")


def _volumetric_targets(path) -> DesignTargets:
    from olti_drake.io.volumetric_io import load_volumetric_result
    from olti_drake.model.volumetric3d import tool_positions

    res = load_volumetric_result(path)
    cfg = res.model.config
    ticks = [np.linspace(*cfg.travel_mm[a], VOLUMETRIC_GRID) for a in AXES]
    grid = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    n_tools = len(cfg.tools)
    cmd, tool = np.tile(grid, (n_tools, 1)), np.repeat(np.arange(n_tools), len(grid))
    T = tool_positions(cfg, res.motions, cmd, tool)
    return DesignTargets(T, cmd + cfg.tools[tool], "best-fit", np.asarray(res.doc["stations_mm"], float),
                         f"the identified tool points of {res.source} on a {VOLUMETRIC_GRID}^3 grid of the travel "
                         f"x {n_tools} tool(s) ({len(T)} targets, best-fit gauge)")


class MachineStationInformation:
    """Per-station sandwich information on the targets and the layout's target u (module docstring).

    ``targets_mm`` (N, 3) where the heads aim; ``nominal_mm`` (N, 3) the gauge's reference positions;
    ``errors`` the budget's per-reading uncertainty (:class:`~olti_drake.io.budget.ReadingErrors`)."""

    def __init__(self, targets_mm, nominal_mm, gauge_kind: str, errors: ReadingErrors):
        self.targets_mm = np.asarray(targets_mm, float)
        n_i = len(self.targets_mm)
        if affine_rank(self.targets_mm) < 3:
            raise InputError(f"the {n_i} targets lie in one plane (or line): the stations' mirror images through "
                             f"it explain every reading alike -- spread the targets over the volume")
        self.errors = errors
        self.nominal_mm, self.gauge_kind = np.asarray(nominal_mm, float), gauge_kind
        A, _, self.gauge = _gauge_rows(gauge_kind, np.asarray(nominal_mm, float), 3 * n_i)
        self._A = A
        self._Z = None
        self._cols = np.arange(3 * n_i)
        self._indptr = np.arange(0, 3 * n_i + 1, 3)

    @property
    def Z(self):
        """The null basis of the gauge rows (dense (3 N_i)², made when the dense path first needs it)."""
        if self._Z is None:
            self._Z = scipy.linalg.null_space(self._A)
        return self._Z

    @property
    def GZ(self):  # the cost is over the targets themselves: G = I
        return self.Z

    def block(self, station_mm):
        """(Sandwich, readings) of one head at ``station_mm`` (3,) mm: it reads every target."""
        diff = self.targets_mm - np.asarray(station_mm, float)
        dist = np.linalg.norm(diff, axis=1)
        n = len(self._cols)
        if dist.min() < MIN_RANGE_MM:
            return Sandwich(np.zeros((n, n)), np.zeros((n, n))), 0
        u = diff / dist[:, None]
        J = sp.csr_matrix((u.ravel(), self._cols, self._indptr), shape=(len(u), n))  # row i: u_iᵀ on p_i
        return station_sandwich(J, u, self.errors.std(dist)), len(u)

    def position_u(self, S) -> np.ndarray:
        """u (mm, k = 1) of every target for the layout information S; inf if the layout cannot solve."""
        return predicted_u(S, self.Z, self.GZ)


#: Values per batch of candidates evaluated at once by :class:`LayoutCosts` (bounds its working memory:
#: a few arrays of this many float64, ~16 MB each).
BATCH_VALUES = 2_000_000
#: A design whose estimated run time (:func:`estimated_seconds`) exceeds this is refused before any work, s.
MAX_DESIGN_SECONDS = 300.0
#: Seconds per unit of work (targets x (4 stations + 6)² per candidate evaluation) of :class:`LayoutCosts`,
#: measured on the shared 2-core machine (with margin): the basis of :func:`estimated_seconds`.
SECONDS_PER_WORK = 1e-8
#: Values kept per candidate and target by :class:`LayoutCosts` (u uᵀ, its weighted twin, the coupling and its
#: weighted twin, the beam direction, the reading u²; float64).
PART_VALUES = 2 * (9 + 12) + 3 + 1
#: The default number of candidate positions (``--step-mm`` not given): the step is chosen from the regions'
#: size so that about this many candidates remain (:func:`default_step_mm`).
DEFAULT_CANDIDATES = 100


class LayoutCosts:
    """The target u of many layouts at once, from the structure of the multilateration (module docstring).

    The same covariance as :meth:`MachineStationInformation.position_u` of the summed sandwiches, without the
    dense (3 N_i)² matrices: with x = (targets p, stations (P_j, L0_j)), the unweighted normal matrix
    N = JᵀJ and the weighted M = Jᵀ diag(u²) J have a block-diagonal target part D (one 3 × 3 block per
    target: Σ_j u_ij u_ijᵀ), a coupling G_j (3 N_i × 4) per station and a 4 × 4 block per station. With the
    gauge rows A on the targets, F = [G_1 … G_Nj, Aᵀ] (r = 4 N_j + 6 columns) and Q = diag(E_1 … E_Nj, 0),
    the constrained inverse H (the (x, x) block of the KKT inverse) of N is, per target i,
    H_p = [D⁻¹, 0] + L Ψ with L = D⁻¹ F S⁻¹, S = Q − Fᵀ D⁻¹ F (r × r), Ψ = [Fᵀ D⁻¹, −E_s]; and the
    covariance block of target i of H M H is W_i + L_i Y_i + (L_i Y_i)ᵀ + L_i Ω L_iᵀ, W_i = D_i⁻¹ D^w_i D_i⁻¹,
    Y_i = F_iᵀ W_i − G^w_iᵀ D_i⁻¹, Ω = Σ_i (Y_i F_i − (D_i⁻¹ F_i)ᵀ G^w_i) + diag(E^w, 0): O(N_i r²) work per
    layout, vectorized over a batch of layouts that differ in one station (the coordinate exchange's step).

    ``targets_mm`` (N, 3), ``nominal_mm`` (N, 3) (the gauge's reference), ``gauge_kind``, ``errors`` (the
    budget's reading u), ``candidates_mm`` (C, 3): the positions whose per-target parts are precomputed."""

    def __init__(self, targets_mm, nominal_mm, gauge_kind: str, errors: ReadingErrors, candidates_mm):
        from olti_drake.limits import check_allocation

        self.targets_mm = np.asarray(targets_mm, float)
        n_i = len(self.targets_mm)
        self.candidates_mm = np.atleast_2d(np.asarray(candidates_mm, float))
        n_c = len(self.candidates_mm)
        check_allocation("--step-mm", f"({n_c} candidates)", [n_c, n_i, PART_VALUES],
                         what="values (candidates x targets x the per-target parts of the normal equations)",
                         hint="use a larger --step-mm or smaller regions")
        A, _, self.gauge = _gauge_rows(gauge_kind, np.asarray(nominal_mm, float), 3 * n_i)
        self.A = A[:, :3 * n_i].reshape(len(A), n_i, 3).transpose(1, 2, 0)  # (N, 3, 6): target i's gauge columns
        self.errors = errors
        self.parts = self._parts(self.candidates_mm)

    def _parts(self, stations_mm) -> dict:
        """Per station (K, …): uu, uuw (N, 3, 3); g, gw (N, 3, 4); e, ew (4, 4); ``reads`` (K,) bool (no
        target closer than :data:`MIN_RANGE_MM`)."""
        P = np.atleast_2d(np.asarray(stations_mm, float))
        out = {k: [] for k in ("uu", "uuw", "g", "gw", "e", "ew", "reads", "u", "w")}
        step = max(1, BATCH_VALUES // (len(self.targets_mm) * 21))
        for s in range(0, len(P), step):
            diff = self.targets_mm[None] - P[s:s + step, None]         # (K, N, 3)
            dist = np.linalg.norm(diff, axis=2)
            out["reads"].append(dist.min(axis=1) >= MIN_RANGE_MM)
            u = diff / np.maximum(dist, MIN_RANGE_MM)[..., None]
            w = self.errors.std(dist.ravel()).reshape(dist.shape) ** 2  # the readings' u², mm²
            a = np.concatenate([u, np.ones(dist.shape + (1,))], axis=2)  # [u, 1]: ∂d/∂(P, L0) = −[u, 1]
            uu = u[..., :, None] * u[..., None, :]
            g = -u[..., :, None] * a[..., None, :]
            e = np.einsum("kni,knj->kij", a, a)
            ew = np.einsum("kni,kn,knj->kij", a, w, a)
            for k, v in (("uu", uu), ("uuw", uu * w[..., None, None]), ("g", g), ("gw", g * w[..., None, None]),
                         ("e", e), ("ew", ew), ("u", u), ("w", w)):
                out[k].append(v)
        return {k: np.concatenate(v) for k, v in out.items()}

    def u(self, base, candidates) -> np.ndarray:
        """(B, N) u (mm, k = 1) of every target for the layouts ``base`` (station indices into the candidates)
        + one candidate of ``candidates`` (B,) each (an empty ``base`` with K stations: pass them all in base
        and ``candidates`` = [-1]); inf for a layout that cannot solve."""
        base = [int(b) for b in base]
        candidates = np.asarray(candidates, int)
        n_i = len(self.targets_mm)
        r = 4 * (len(base) + (candidates[0] >= 0)) + 6
        step = max(1, BATCH_VALUES // (n_i * 3 * r))
        return np.concatenate([self._u(base, candidates[s:s + step]) for s in range(0, len(candidates), step)])

    def _u(self, base, cand) -> np.ndarray:
        p = self.parts
        extra = cand[0] >= 0
        B, n_i = len(cand), len(self.targets_mm)
        sel = (lambda k: p[k][base].sum(axis=0)[None] + (p[k][cand] if extra else 0.0))
        D, Dw = sel("uu"), sel("uuw")                                     # (B, N, 3, 3)
        stations = len(base) + int(extra)
        r = 4 * stations + 6

        def stack(key):  # (B, N, 3, 4 Nj): the coupling columns of every station of each layout
            cols = [np.broadcast_to(p[key][b][None], (B, n_i, 3, 4)) for b in base]
            if extra:
                cols.append(p[key][cand])
            return np.concatenate(cols, axis=3)

        F = np.concatenate([stack("g"), np.broadcast_to(self.A[None], (B, n_i, 3, 6))], axis=3)  # (B, N, 3, r)
        Gw = np.concatenate([stack("gw"), np.zeros((B, n_i, 3, 6))], axis=3)
        Q, Qw = np.zeros((B, r, r)), np.zeros((B, r, r))
        for k, b in enumerate(base + ([None] if extra else [])):
            e, ew = (p["e"][b], p["ew"][b]) if b is not None else (p["e"][cand], p["ew"][cand])
            Q[:, 4 * k:4 * k + 4, 4 * k:4 * k + 4] = e
            Qw[:, 4 * k:4 * k + 4, 4 * k:4 * k + 4] = ew
        Dinv, bad = _inv3(D)                                              # (B, N, 3, 3), (B,)
        W = _m3(_m3(Dinv, Dw), Dinv)
        # A station's coupling is rank one per target, g_ij = −u_ij a_ijᵀ (a = [u, 1]), and its weighted one
        # w_ij g_ij: D⁻¹ g = −(D⁻¹ u) aᵀ, W g = −(W u) aᵀ -- matrix-vector products, not 3 x r ones.
        us, a, w = self._per_station(base, cand, B)                        # (B, N, J, 3), (B, N, J, 4), (B, N, J)
        v, Wu = _mv(Dinv, us), _mv(W, us)
        outer = (lambda x: -(x[..., :, None] * a[..., None, :]).transpose(0, 1, 3, 2, 4).reshape(B, n_i, 3, -1))
        AB = np.broadcast_to(self.A[None], (B, n_i, 3, 6))
        DF = np.concatenate([outer(v), _m3(Dinv, AB)], axis=3)            # (B, N, 3, r)
        Yt_ = np.concatenate([outer(Wu - w[..., None] * v), _m3(W, AB)], axis=3)  # Y_iᵀ (D⁻¹, W symmetric)
        Ft, n3 = F.reshape(B, 3 * n_i, r), 3 * n_i
        S = Q - np.swapaxes(Ft, 1, 2) @ DF.reshape(B, n3, r)
        # Singular S (a layout the multilateration cannot solve, e.g. coplanar stations): inf. Scaled by its
        # diagonal, as the rank check of the reduced normal matrix is.
        d = np.sqrt(np.maximum(np.abs(np.einsum("bii->bi", S)), 1e-300))
        sv = np.linalg.svd(S / d[:, :, None] / d[:, None, :], compute_uv=False)
        bad |= sv[:, -1] <= 1e-10 * sv[:, 0]
        S = np.where(bad[:, None, None], np.eye(r), S)
        L = DF.reshape(B, n3, r) @ np.linalg.inv(S)                      # (B, 3N, r)
        Yt = Yt_.reshape(B, n3, r)
        Omega = (np.swapaxes(Yt, 1, 2) @ Ft - np.swapaxes(DF.reshape(B, n3, r), 1, 2) @ Gw.reshape(B, n3, r)
                 + Qw)
        u2 = (np.einsum("bnkk->bn", W) + 2 * (L * Yt).reshape(B, n_i, 3 * r).sum(axis=2)
              + ((L @ Omega) * L).reshape(B, n_i, 3 * r).sum(axis=2))
        u = np.sqrt(np.maximum(u2, 0.0))
        u[bad] = np.inf
        return u

    def _per_station(self, base, cand, B):
        """(u (B, N, J, 3), a = [u, 1] (B, N, J, 4), reading u² (B, N, J)) of the J stations of each layout."""
        p = self.parts
        idx = [np.full(B, b) for b in base] + ([cand] if cand[0] >= 0 else [])
        us = np.stack([p["u"][i] for i in idx], axis=2)
        w = np.stack([p["w"][i] for i in idx], axis=2)
        return us, np.concatenate([us, np.ones(w.shape + (1,))], axis=3), w

    def layout_u(self, stations_mm) -> np.ndarray:
        """(N,) target u (mm) of one given layout (K, 3) mm (e.g. the result's own stations)."""
        keep = self.candidates_mm, self.parts
        try:
            self.candidates_mm = np.atleast_2d(np.asarray(stations_mm, float))
            self.parts = self._parts(self.candidates_mm)
            if not self.parts["reads"].all():
                return np.full(len(self.targets_mm), np.inf)
            return self.u(range(len(self.candidates_mm)), [-1])[0]
        finally:
            self.candidates_mm, self.parts = keep


def _m3(A, B):
    """A (…, 3, 3) times B (…, 3, m), batched: three broadcast products (faster than matmul's loop over tiny
    matrices)."""
    return A[..., :, 0, None] * B[..., None, 0, :] + A[..., :, 1, None] * B[..., None, 1, :] \
        + A[..., :, 2, None] * B[..., None, 2, :]


def _inv3(D):
    """The inverses of symmetric positive semi-definite 3 x 3 blocks D (B, N, 3, 3) by their cofactors, and
    which layouts (B,) have a singular one (det <= 1e-12 x (trace / 3)³: a target seen from one plane)."""
    a, b, c = D[..., 0, 0], D[..., 0, 1], D[..., 0, 2]
    e, f, i = D[..., 1, 1], D[..., 1, 2], D[..., 2, 2]
    A, B_, C = e * i - f * f, c * f - b * i, b * f - c * e
    E, F, I = a * i - c * c, b * c - a * f, a * e - b * b
    det = a * A + b * B_ + c * C
    tr = (a + e + i) / 3.0
    singular = det <= 1e-12 * np.maximum(tr, 1e-300) ** 3
    det = np.where(singular, 1.0, det)
    inv = np.stack([A, B_, C, B_, E, F, C, F, I], axis=-1).reshape(D.shape) / det[..., None, None]
    return inv, singular.any(axis=1)


def _mv(A, x):
    """A (B, N, 3, 3) times every vector of x (B, N, J, 3): (B, N, J, 3)."""
    return A[:, :, None, :, 0] * x[..., 0, None] + A[:, :, None, :, 1] * x[..., 1, None] \
        + A[:, :, None, :, 2] * x[..., 2, None]


def estimated_seconds(n_targets: int, n_candidates: int, n_stations: int, starts: int, max_sweeps: int) -> float:
    """The coordinate exchange's run time at most, s (:data:`SECONDS_PER_WORK`): every sweep of every start
    evaluates every candidate in every slot."""
    evaluations = float(starts) * max_sweeps * n_stations * n_candidates
    return evaluations * n_targets * (4 * n_stations + 6) ** 2 * SECONDS_PER_WORK


def default_step_mm(boxes, targets_mm) -> float:
    """The candidate step when ``--step-mm`` is not given: the boxes' volume (or area, length) split into about
    :data:`DEFAULT_CANDIDATES` cells, no finer than 1/20 of the targets' largest extent (the machine's size),
    rounded up to 5 mm."""
    boxes = np.asarray(boxes, float)
    extent = float(np.ptp(np.asarray(targets_mm, float), axis=0).max())
    sizes = boxes[:, :, 1] - boxes[:, :, 0]
    dims = int(max((sizes > 0).sum(axis=1).max(), 1))
    content = float(sum(np.prod(s[s > 0]) for s in sizes if (s > 0).any()))
    step = max((content / DEFAULT_CANDIDATES) ** (1.0 / dims) if content > 0 else 0.0, extent / 20.0, 1.0)
    step = float(np.ceil(step / 5.0) * 5.0)

    def count(h):  # the candidates serial_design.candidate_points makes at step h (ends included)
        return sum(np.prod([np.floor((hi - lo + 1e-9) / h) + 1 if hi > lo else 1 for lo, hi in box]) for box in boxes)

    for _ in range(400):  # (the volume's estimate leaves out the ends: coarser until about the count is met)
        if count(step) <= DEFAULT_CANDIDATES:
            break
        step += 5.0
    return step


def check_design_space(candidates_mm, n_stations: int, n_targets: int, regions: str = "the regions") -> None:
    """Refuse, by name, a design every layout of which is degenerate (module docstring)."""
    if n_stations < 4:
        raise InputError(f"--stations {n_stations}: 3D self-calibrating multilateration needs at least 4 stations "
                         f"(each has 4 unknowns, the gauge 6: 001 Eq. (4) in 3D)")
    need = counting_bound(n_stations, 3)
    if not n_targets > need:
        raise InputError(f"counting condition: {n_targets} targets with {n_stations} stations; 3D needs "
                         f"N_i > (4 N_j - 6)/(N_j - 3) = {need:g} (001 Eq. (4)) -- fewer stations or more targets")
    if affine_rank(candidates_mm) < 3:
        raise InputError(f"{regions}: every candidate station position lies in one plane: coplanar stations "
                         f"cannot separate a target's offset across that plane from the dead paths -- give boxes at "
                         f"different heights (z_mm) or one box with a z range")


def design_machine_stations(info: MachineStationInformation, candidates_mm, n_stations: int, *,
                            criterion: str = "max", seed: int = 0, starts: int = 3, max_sweeps: int = 5,
                            min_separation_mm: float = 100.0, regions: str = "the regions", progress=None, **where):
    """Coordinate exchange over the candidates for ``n_stations`` heads (:func:`_exchange`, the serial design's
    rule, every slot's candidates evaluated at once by :class:`LayoutCosts`), after the degeneracy checks and
    the run-time estimate (:func:`check_design_time`); refuses a design whose best layout cannot solve.
    ``progress(start, sweep, cost_mm)`` is called after every sweep. ``where``: the starts' ``workers``,
    ``backend``, ``scheduler`` (:func:`olti_drake.estimation.serial_design.coordinate_exchange`)."""
    from olti_drake.threads import single_thread_blas

    cand = np.atleast_2d(np.asarray(candidates_mm, float))
    check_design_space(cand, n_stations, len(info.targets_mm), regions)
    check_design_time(len(info.targets_mm), len(cand), n_stations, starts, max_sweeps)
    if criterion not in ("max", "mean"):
        raise InputError(f"criterion: 'max' or 'mean', not {criterion!r}")
    costs = LayoutCosts(info.targets_mm, info.nominal_mm, info.gauge_kind, info.errors, cand)
    with single_thread_blas():  # many small products: threads only contend
        d = _exchange(costs, n_stations, criterion, seed, starts, max_sweeps, min_separation_mm, progress, where)
    if not np.isfinite(d.cost_mm):
        raise InputError(f"{regions}: no layout of {n_stations} stations found by {starts} start(s) that the "
                         f"multilateration can solve (stations in one plane or line): widen the regions")
    return d


def evaluate_machine_layout(info: MachineStationInformation, stations_mm, criterion: str = "max") -> dict:
    """Cost of a given layout (e.g. the result's own stations), mm; inf when it cannot solve (:class:`LayoutCosts`:
    the same u as the dense per-station sandwich of :meth:`MachineStationInformation.position_u`)."""
    S = np.atleast_2d(np.asarray(stations_mm, float))
    costs = LayoutCosts(info.targets_mm, info.nominal_mm, info.gauge_kind, info.errors, S)
    u = costs.layout_u(S)
    n = len(info.targets_mm)
    return {"stations_mm": S.tolist(), "readings": [int(n) if r else 0 for r in costs.parts["reads"]],
            "max_u_mm": float(np.max(u)), "mean_u_mm": float(np.mean(u)),
            "cost_mm": float(np.max(u) if criterion == "max" else np.mean(u))}


def check_design_time(n_targets: int, n_candidates: int, n_stations: int, starts: int, max_sweeps: int) -> None:
    """Refuse, in one line before any work, a design whose estimated run time (:func:`estimated_seconds`) exceeds
    :data:`MAX_DESIGN_SECONDS`, naming the settings that size it."""
    t = estimated_seconds(n_targets, n_candidates, n_stations, starts, max_sweeps)
    if t > MAX_DESIGN_SECONDS:
        held = float(n_candidates) * n_targets * PART_VALUES * 8
        raise InputError(f"{n_candidates} candidates x {n_targets} targets x {n_stations} stations x {starts} start(s) "
                         f"x {max_sweeps} sweep(s): the design would run up to ~"
                         + (f"{t / 3600:.3g} h" if t >= 3600 else f"{t / 60:.3g} min")
                         + f" (at most {MAX_DESIGN_SECONDS / 60:g} min) and hold {held / 1e9:.3g} GB of per-candidate "
                         f"parts -- use a larger --step-mm, smaller regions, fewer --starts or --max-sweeps")


def _exchange(costs: LayoutCosts, n_stations: int, criterion: str, seed: int, starts: int, max_sweeps: int,
              min_separation_mm: float, progress=None, where=None):
    """The coordinate exchange of :func:`olti_drake.estimation.serial_design.design_stations` (seeded random
    starts of feasible candidates pairwise ``min_separation_mm`` apart; per sweep, each slot takes the candidate
    that lowers the cost most), every slot's candidates evaluated in one batch."""
    from olti_drake.estimation.serial_design import StationDesign, coordinate_exchange

    cand = costs.candidates_mm
    reads = costs.parts["reads"]
    feasible = np.flatnonzero(reads)
    if len(feasible) < n_stations:
        raise InputError(f"only {len(feasible)} candidate position(s) are at least {MIN_RANGE_MM:g} mm from every "
                         f"target; {n_stations} stations are needed: widen the regions")
    score = (lambda u: np.max(u, axis=-1)) if criterion == "max" else (lambda u: np.mean(u, axis=-1))
    best, best_cost, evaluations = coordinate_exchange(
        cand, feasible, n_stations, lambda layout: score(costs.u(layout, [-1])[0]),
        lambda others, trial: score(costs.u(others, trial)), seed=seed, starts=starts, max_sweeps=max_sweeps,
        min_separation_mm=min_separation_mm, progress=progress, **(where or {}))
    u = costs.u(best, [-1])[0]
    readings = np.where(reads, len(costs.targets_mm), 0)
    return StationDesign(cand[best], best_cost, criterion, cand, readings, evaluations, starts, u)


def machine_design_document(design, current, targets: DesignTargets, *, budget_name: str, result: str, regions: str,
                            step_mm: float, seed: int, max_sweeps: int, min_separation_mm: float, gauge: str,
                            elapsed_s: float) -> dict:
    """The ``DESIGN.json`` of a machine tool's station design (``olti-design/1``), mm; u standard (k = 1)."""
    designed = {"stations_mm": design.stations_mm.tolist(), "max_u_mm": float(np.max(design.u_mm)),
                "mean_u_mm": float(np.mean(design.u_mm)), "cost_mm": design.cost_mm}
    improvement = None
    if current is not None and np.isfinite(current["cost_mm"]) and design.cost_mm > 0:
        improvement = current["cost_mm"] / design.cost_mm
    return {"format": FORMAT, "kind": "machine tool, 3D multilateration", "criterion": design.criterion, "k": 1,
            "method": "linear propagation (JCGM 100) of the budget through the unweighted multilateration: per-station "
                      "sandwich information with the station's own unknowns projected out, the result's 3D gauge, "
                      "coordinate exchange from seeded starts (olti_drake.estimation.machine_design)",
            "budget": budget_name, "result": result, "targets": targets.what, "regions": regions,
            "stations_mm": designed["stations_mm"], "current": current, "designed": designed,
            "improvement": improvement, "evaluations": design.evaluations, "seed": seed, "starts": design.starts,
            "max_sweeps": max_sweeps, "gauge": gauge, "u_targets_mm": design.u_mm.tolist(),
            "candidates": {"step_mm": step_mm, "count": int(len(design.candidates_mm))},
            "rules": {"min_separation_mm": min_separation_mm,
                      "line_of_sight": "pan/tilt heads: every target is read from every station"},
            "elapsed_s": round(elapsed_s, 3)}
