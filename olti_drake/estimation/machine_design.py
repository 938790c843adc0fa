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
#: The per-station information of every candidate is kept (each is evaluated once): at most this many bytes.
MAX_BLOCK_BYTES = 2e9
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
        A, _, self.gauge = _gauge_rows(gauge_kind, np.asarray(nominal_mm, float), 3 * n_i)
        self.Z = scipy.linalg.null_space(A)
        self.GZ = self.Z  # the cost is over the targets themselves: G = I
        self._cols = np.arange(3 * n_i)
        self._indptr = np.arange(0, 3 * n_i + 1, 3)

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
                            min_separation_mm: float = 100.0, regions: str = "the regions"):
    """Coordinate exchange (:func:`~olti_drake.estimation.serial_design.design_stations`) over the candidates
    for ``n_stations`` heads, after the degeneracy checks; refuses a design whose best layout cannot solve."""
    from olti_drake.estimation.serial_design import design_stations

    check_design_space(candidates_mm, n_stations, len(info.targets_mm), regions)
    need = 2 * len(candidates_mm) * (3 * len(info.targets_mm)) ** 2 * 8  # two dense (n, n) blocks per candidate
    if need > MAX_BLOCK_BYTES:
        raise InputError(f"{len(info.targets_mm)} targets x {len(candidates_mm)} candidates need {need / 1e9:.1f} GB "
                         f"of per-station information (at most {MAX_BLOCK_BYTES / 1e9:g} GB): use a larger --step-mm "
                         f"or smaller regions")
    d = design_stations(info, candidates_mm, n_stations, criterion=criterion, seed=seed, starts=starts,
                        max_sweeps=max_sweeps, min_separation_mm=min_separation_mm)
    if not np.isfinite(d.cost_mm):
        raise InputError(f"{regions}: no layout of {n_stations} stations found by {starts} start(s) that the "
                         f"multilateration can solve (stations in one plane or line): widen the regions")
    return d


def evaluate_machine_layout(info: MachineStationInformation, stations_mm, criterion: str = "max") -> dict:
    """Cost of a given layout (e.g. the result's own stations), mm; inf when it cannot solve."""
    from olti_drake.estimation.serial_design import evaluate_layout

    return evaluate_layout(info, np.atleast_2d(np.asarray(stations_mm, float)), criterion)


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
