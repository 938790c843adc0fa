"""Self-calibrating multilateration of paper 001 §2.3 (Eq. 2-6), on the shared least-squares program.

Unknowns (Eq. 4, in 2D): the target positions p_i, the station (rotary-table
interferometer) positions P_j and the dead paths L0_j; readings
ΔL_ij = ‖p_i − P_j‖ − L0_j (Eq. 3). Distances cannot see where the frame is:
two translations and one rotation (the 2D counterpart of 001's six
constraints) are fixed explicitly as linear constraints and stated in the
result's ``gauge``.

Counting (2D): 2N_i + 3N_j − 3 unknowns against N_i·N_j readings, so
N_i > (3N_j − 3)/(N_j − 2) with N_j ≥ 3 (001 gives the 3D form
N_i > (4N_j − 6)/(N_j − 3)). Geometry that leaves the problem singular (e.g.
stations on one line with the targets) is caught by the rank check.

Units: mm.
"""

import os
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from olti_drake.io.csvio import (InputError, check_finite, check_indices, check_no_duplicate_rows, check_spread, check_values,
                    json_numbers, read_json,
                    read_table)
from olti_drake.model.scara import rows_to_csr
from olti_drake.estimation.calibration import distance_rows, station_fit  # noqa: F401 (station_fit re-exported)
from olti_drake.estimation.leastsquares import LeastSquaresProgram, SolverOptions, UnidentifiableError

FORMAT = "olti-multilateration/1"
REQUIRED = ("station", "target", "x_cmd_mm", "y_cmd_mm", "displacement_mm")
GAUGES = ("best-fit", "first-two")
#: ∂p/∂(p_x, p_y) of a free point: the identity, as the rows of :func:`calibration.distance_rows`.
_UNIT_X, _UNIT_Y = np.array([1.0, 0.0]), np.array([0.0, 1.0])


@dataclass(frozen=True)
class MachineCampaign:
    """Valid readings of a machine-tool campaign (formats.md): station j, target i, ΔL_ij (mm).

    ``commands_mm`` (N_i, 2) is the command position p*_i of every target index.
    """

    station: np.ndarray
    target: np.ndarray
    commands_mm: np.ndarray
    displacement_mm: np.ndarray
    line: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return self.station.size

    @property
    def n_stations(self) -> int:
        return int(self.station.max()) + 1

    @property
    def n_targets(self) -> int:
        return len(self.commands_mm)


def load_machine_campaign(path) -> MachineCampaign:
    """Load a machine-tool campaign CSV (formats.md); skip ``valid`` = 0 rows.

    One-line errors name file, line and column; the same target index must
    carry the same command position on every row.
    """
    return machine_campaign(read_table(path, REQUIRED, ("valid",), integer=("station", "target", "valid")),
                            os.fspath(path))


def machine_campaign(columns: dict, source: str = "campaign") -> MachineCampaign:
    """Validate campaign columns (formats.md names; ``_line`` optional) into a :class:`MachineCampaign`."""
    t = {k: np.asarray(v, dtype=float) for k, v in columns.items() if k != "_line"}
    t["_line"] = np.asarray(columns.get("_line", np.arange(2, len(t["station"]) + 2)), dtype=int)
    if "valid" in t:
        check_values(t, source, "valid", (0.0, 1.0))
        t = {k: v[t["valid"] == 1] for k, v in t.items()}
    if not len(t["_line"]):
        raise InputError(f"{source}: no valid readings")
    if "_same_as" in columns:
        t["_same_as"] = t["_same_as"].astype(int)
        check_no_duplicate_rows(t, source)
    check_finite(t, source, REQUIRED)
    i, j = check_indices(t, source, "target"), check_indices(t, source, "station")
    xy = np.column_stack([t["x_cmd_mm"], t["y_cmd_mm"]])
    cmd = np.full((i.max() + 1, 2), np.nan)
    cmd[i[::-1]] = xy[::-1]  # the first row of a target defines its command
    clash = np.flatnonzero(np.any(np.abs(cmd[i] - xy) > 1e-9, axis=1))
    if clash.size:
        k = clash[0]
        raise InputError(f"{source}:{t['_line'][k]}: target {i[k]} has command ({xy[k, 0]:g}, {xy[k, 1]:g}) mm, "
                         f"but ({cmd[i[k], 0]:g}, {cmd[i[k], 1]:g}) mm elsewhere")
    size = np.hypot(*np.ptp(cmd, axis=0))
    check_spread(t["displacement_mm"], j, t["_line"], source, "displacement_mm", 1.5 * size + 10.0, "station",
                 f"the {size:g} mm diagonal of the commands, with a margin")
    return MachineCampaign(j, i, cmd, t["displacement_mm"], t["_line"], source)


@dataclass
class MultilaterationOptions(SolverOptions):
    """Solver options plus: initial station positions (mm, e.g. from the rotation-centre
    estimate of 001 §2.2) and the gauge (``best-fit``: the estimated targets have no mean
    translation or rotation from their commands; ``first-two``: target 0 at its command, target 1
    on the line of its command direction)."""

    stations_mm: Optional[np.ndarray] = None
    gauge: str = "best-fit"


@dataclass
class MultilaterationResult:
    """Estimated targets (N_i, 2), stations (N_j, 2), dead paths (N_j,) mm, uncertainties (k = 1)."""

    targets_mm: np.ndarray
    stations_mm: np.ndarray
    dead_paths_mm: np.ndarray
    targets_std_mm: np.ndarray
    fit: object
    gauge: str
    commands_mm: np.ndarray = field(default=None)
    gauge_kind: str = "best-fit"
    #: The campaign solved from: {"readings": N, "sha256": ...} (:func:`campaign_io.campaign_digest`).
    campaign: dict = field(default_factory=dict)

    @property
    def residual_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.fit.residuals ** 2)))

    def to_dict(self) -> dict:
        """The machine-tool ``result.json`` of formats.md."""
        f = self.fit
        n_i, n_j = len(self.targets_mm), len(self.stations_mm)
        std = f.std
        return {"format": FORMAT, "targets_mm": self.targets_mm.tolist(), "stations_mm": self.stations_mm.tolist(),
                "dead_paths_mm": self.dead_paths_mm.tolist(), "gauge": self.gauge, "gauge_kind": self.gauge_kind,
                "residual_rms_mm": self.residual_rms_mm, "n_readings": int(len(f.residuals)),
                "commands_mm": self.commands_mm.tolist(),
                "uncertainty": {"k": 1, "targets_mm": self.targets_std_mm.tolist(),
                                "stations_mm": std[2 * n_i:2 * n_i + 2 * n_j].reshape(-1, 2).tolist(),
                                "dead_paths_mm": std[2 * n_i + 2 * n_j:].tolist(),
                                "method": "linear propagation (JCGM 100): " + (
                                    "of the budget" if any("budget" in n for n in f.notes)
                                    else "of the residual variance")},
                "iterations": f.iterations, "condition_number": f.condition_number, "solver": f.solver,
                "outliers": f.outliers, "converged": f.converged_by, "warnings": list(f.warnings),
                **({"campaign": self.campaign} if self.campaign else {}), **({"notes": f.notes} if f.notes else {})}


class Multilateration(LeastSquaresProgram):
    """The self-calibrating multilateration problem (001 Eq. 2-6) as a Drake MathematicalProgram.

    Variables ``p{i}_x_mm``, ``p{i}_y_mm``, ``P{j}_x_mm``, ``P{j}_y_mm``, ``L0_{j}_mm``.
    """

    rank_hint = "check the station layout: stations on one line with the targets cannot locate them"
    untouched_hint = "every target needs readings from the stations"

    def __init__(self, data: MachineCampaign, options: MultilaterationOptions = None):
        o = options or MultilaterationOptions()
        if o.gauge not in GAUGES:
            raise InputError(f"gauge must be one of {', '.join(GAUGES)}, got {o.gauge!r}")
        self.data = data
        self._check_counts()
        n_i, n_j = data.n_targets, data.n_stations
        self._declare([f"p{i}_{c}_mm" for i in range(n_i) for c in "xy"]
                      + [f"P{j}_{c}_mm" for j in range(n_j) for c in "xy"] + [f"L0_{j}_mm" for j in range(n_j)], o)
        self.x0 = self._initial_guess()
        self.gauge = self._add_gauge()

    #: A station farther than this many command spans from the command centroid is absurd.
    STATION_SPANS = 100.0
    #: A target estimated farther than this fraction of the command span from its command is absurd.
    TARGET_SPAN_FRACTION = 0.1

    def implausible(self, x) -> list:
        """Stations beyond :attr:`STATION_SPANS` command spans from the command centroid, or targets more than
        :attr:`TARGET_SPAN_FRACTION` of the span off their commands (a machine's errors are far smaller)."""
        c = self.data.commands_mm
        n_i, n_j = self.data.n_targets, self.data.n_stations
        span = max(float(np.ptp(c, axis=0).max()), 1e-9)
        out = []
        far = np.hypot(*(x[2 * n_i:2 * n_i + 2 * n_j].reshape(-1, 2) - c.mean(axis=0)).T)
        if far.max() > self.STATION_SPANS * span:
            j = int(np.argmax(far))
            out.append(f"station {j} lies {far[j]:.6g} mm from the command centroid, over {self.STATION_SPANS:g} "
                       f"x the command span {span:g} mm")
        off = np.hypot(*(x[:2 * n_i].reshape(-1, 2) - c).T)
        if off.max() > self.TARGET_SPAN_FRACTION * span:
            i = int(np.argmax(off))
            out.append(f"target {i} is estimated {off[i]:.6g} mm from its command, over "
                       f"{self.TARGET_SPAN_FRACTION:g} x the command span {span:g} mm")
        return out

    def default_budget(self):
        """The budget given to :meth:`solve`, else 001 Table 4: the residual is compared with its reading u."""
        from olti_drake.io.budget import default_budget

        return getattr(self, "_solve_budget", None) or default_budget("machine")

    def _check_counts(self):
        d = self.data
        n_i, n_j = d.n_targets, d.n_stations
        if n_j < 3:
            raise UnidentifiableError(
                f"{d.source}: {n_j} station position(s); 2D self-calibrating multilateration needs at least 3 "
                f"(each target has 2 unknowns and each station 3, less the 3 of the gauge) -- the stations and "
                f"dead paths are not identifiable", [f"P{j}" for j in range(n_j)])
        need = (3 * n_j - 3) / (n_j - 2)
        if not n_i > need:
            raise UnidentifiableError(
                f"{d.source}: {n_i} targets with {n_j} stations; 2D needs N_i > (3 N_j - 3)/(N_j - 2) = {need:g} "
                f"(unknowns 2 N_i + 3 N_j - 3 against N_i N_j readings; 001 Eq. (4) counts it in 3D)")
        seen = np.zeros((n_i, n_j), dtype=bool)
        seen[d.target, d.station] = True
        lonely = np.flatnonzero(seen.sum(axis=1) < 2)
        if lonely.size:
            raise UnidentifiableError(f"{d.source}: target {lonely[0]} is read from {seen[lonely[0]].sum()} station(s); "
                                      f"a 2D position needs at least 2 (and redundancy more)",
                                      [f"p{lonely[0]}_x_mm", f"p{lonely[0]}_y_mm"])

    def residual_rows(self, X, displacement_mm=None):
        """Eq. (3) of 001 for T parameter vectors at once, Jacobian row-compressed (for the Monte Carlo).

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`), mm.
            displacement_mm: readings ΔL_ij (K,) or per trial (T, K), mm; default the campaign's.

        Returns:
            r (T, K) = ‖p_i − P_j‖ − L0_j − ΔL_ij, mm; cols (K, 5) parameter indices shared by all
            trials (p_i x, y; P_j x, y; L0_j); vals (T, K, 5) the matching dr/dx entries (u, −u, −1),
            u the unit vector from P_j to p_i.
        """
        X = np.atleast_2d(X)
        d = self.data
        n_i, n_j = d.n_targets, d.n_stations
        p = X[:, :2 * n_i].reshape(len(X), n_i, 2)[:, d.target]  # free points: the position model is x itself
        P = X[:, 2 * n_i:2 * n_i + 2 * n_j].reshape(len(X), n_j, 2)
        readings = d.displacement_mm if displacement_mm is None else displacement_mm
        pcols = np.column_stack([2 * d.target, 2 * d.target + 1])
        return distance_rows(p, pcols, _UNIT_X, _UNIT_Y, P, X[:, 2 * n_i + 2 * n_j:], d.station, readings,
                             2 * n_i, 2 * n_i + 2 * n_j)

    def residuals(self, x):
        """Eq. (3) of 001: r = ‖p_i − P_j‖ − L0_j − ΔL_ij (mm) and the sparse Jacobian."""
        r, cols, vals = self.residual_rows(np.asarray(x)[None])
        return r[0], rows_to_csr(cols, vals[0], len(self.names))

    def reading_label(self, k: int) -> dict:
        return {"line": int(self.data.line[k]), "station": int(self.data.station[k]),
                "target": int(self.data.target[k])}

    def layout(self, v) -> dict:
        """A parameter-shaped vector (e.g. uncertainties) in the result's keys and shapes (formats.md)."""
        n_i, n_j = self.data.n_targets, self.data.n_stations
        v = np.asarray(v, dtype=float)
        return {"targets_mm": v[:2 * n_i].reshape(-1, 2).tolist(),
                "stations_mm": v[2 * n_i:2 * n_i + 2 * n_j].reshape(-1, 2).tolist(),
                "dead_paths_mm": v[2 * n_i + 2 * n_j:].tolist()}

    def beam_lengths(self, x) -> np.ndarray:
        """‖p_i − P_j‖ of every reading at x, mm."""
        r, _ = self.residuals(x)
        return r + x[2 * self.data.n_targets + 2 * self.data.n_stations:][self.data.station] + self.data.displacement_mm

    def _initial_guess(self) -> np.ndarray:
        """Targets at their commands (001 §2.3), stations from the data or the given estimates."""
        d, o = self.data, self.options
        S = None if o.stations_mm is None else np.asarray(o.stations_mm, dtype=float).reshape(-1, 2)
        if S is not None and len(S) != d.n_stations:
            raise InputError(f"stations_mm gives {len(S)} positions but the campaign has {d.n_stations} stations")
        fits = []
        for j in range(d.n_stations):
            try:
                fits.append(station_fit(d.commands_mm[d.target[d.station == j]], d.displacement_mm[d.station == j],
                                        None if S is None else S[j]))
            except ValueError as e:
                raise UnidentifiableError(f"{d.source}: station {j}: not identifiable: P{j}_x_mm, P{j}_y_mm -- the "
                                          f"targets it reads lie on one line ({e})",
                                          [f"P{j}_x_mm", f"P{j}_y_mm"]) from None
        return np.concatenate([d.commands_mm.ravel(), np.ravel([f[0] for f in fits]), [f[1] for f in fits]])

    def _add_gauge(self) -> str:
        c = self.data.commands_mm
        n = len(self.names)
        A = np.zeros((3, n))
        if self.options.gauge == "best-fit":
            A[0, 0:2 * len(c):2] = 1.0  # Σ (p_i − p*_i)_x = 0
            A[1, 1:2 * len(c):2] = 1.0
            rel = c - c.mean(axis=0)  # Σ (p*_i − c) × (p_i − p*_i) = 0: no mean rotation about the centroid
            A[2, 0:2 * len(c):2], A[2, 1:2 * len(c):2] = -rel[:, 1], rel[:, 0]
            b = A[:, :2 * len(c)] @ c.ravel()
            text = ("two translations and the rotation fixed by linear constraints: the estimated targets have no "
                    "mean translation and no mean rotation (about the command centroid) from their command "
                    "positions -- the frame best fits the commands")
        else:
            e = c[1] - c[0]
            A[0, 0], A[1, 1] = 1.0, 1.0
            A[2, 2], A[2, 3] = -e[1], e[0]  # target 1 on the line through p*_0 along p*_1 − p*_0
            b = np.array([c[0, 0], c[0, 1], -e[1] * c[0, 0] + e[0] * c[0, 1]])
            text = ("origin fixed at target 0's command position and the X direction along the command "
                    "direction from target 0 to target 1 (target 1 constrained to that line)")
        self.prog.AddLinearEqualityConstraint(A, b, self.variables).evaluator().set_description("gauge")
        return text

    def solve(self, budget=None) -> MultilaterationResult:
        """Check counts and geometry, solve Eq. (2) of 001, and propagate the uncertainty.

        With a ``budget`` (e.g. 001 Table 4) the standard uncertainties are its
        linear propagation (JCGM 100) -- with few redundant readings (3
        stations: N_i − 6 degrees of freedom) the residuals alone estimate the
        reading noise poorly; without one, the residual-based propagation.
        """
        from olti_drake.io.campaign_io import campaign_digest

        self._solve_budget = budget
        f = self.fit()
        if budget is not None:
            from olti_drake.estimation.uncertainty import linear_covariance  # builds on this layer
            from olti_drake.io.budget import ReadingErrors

            f.covariance = linear_covariance(self, f.x, ReadingErrors(budget))
            f.std = np.sqrt(np.maximum(np.diag(f.covariance), 0))
            f.notes.append(f"uncertainty: linear propagation of the budget '{budget.name}'")
        n_i, n_j = self.data.n_targets, self.data.n_stations
        return MultilaterationResult(f.x[:2 * n_i].reshape(-1, 2), f.x[2 * n_i:2 * n_i + 2 * n_j].reshape(-1, 2),
                                     f.x[2 * n_i + 2 * n_j:], f.std[:2 * n_i].reshape(-1, 2), f, self.gauge,
                                     self.data.commands_mm, self.options.gauge, campaign_digest(self.data))


def load_result(path) -> dict:
    """Read a machine-tool result.json (formats.md), its schema checked where it is read: targets N x 2,
    stations M x 2 and dead paths M (mm; commands N x 2 and standard uncertainties of the same shapes,
    >= 0, when present), every number finite and within +-1e5 mm, ``gauge`` a sentence; a SCARA result
    or a campaign is refused by its ``format``. Errors are one line naming the file and the key."""
    name = os.fspath(path)
    data = read_json(path, FORMAT, "a machine-tool result (olti multilaterate)")
    T = json_numbers(data, name, "targets_mm", (None, 2))
    S = json_numbers(data, name, "stations_mm", (None, 2))
    json_numbers(data, name, "dead_paths_mm", (len(S),))
    if "commands_mm" in data:
        json_numbers(data, name, "commands_mm", T.shape)
    if not isinstance(data.get("gauge"), str):
        raise InputError(f"{name}: key 'gauge': expected the sentence stating the gauge, got {data.get('gauge')!r}")
    unc = data.get("uncertainty")
    for key, shape in (("targets_mm", T.shape), ("stations_mm", S.shape), ("dead_paths_mm", (len(S),))):
        if isinstance(unc, dict) and key in unc:
            if np.any(json_numbers(unc, name, key, shape, label=f"uncertainty.{key}") < 0):
                raise InputError(f"{name}: key 'uncertainty.{key}': a standard uncertainty is < 0")
    data.setdefault("gauge_kind", "first-two" if "target 0" in data["gauge"] else "best-fit")
    if data["gauge_kind"] not in GAUGES:
        raise InputError(f"{name}: key 'gauge_kind' must be one of {', '.join(GAUGES)}, got {data['gauge_kind']!r}")
    return data


def align_to_commands(points_mm, commands_mm, *others_mm):
    """Move points rigidly into the ``best-fit`` gauge: no mean translation, no mean rotation from commands.

    The rigid motion (rotation about the command centroid, then translation)
    that makes ``points`` satisfy the best-fit gauge constraints exactly is
    applied to ``points`` and to every array in ``others`` (e.g. the true
    station positions), so a truth or a reference instrument can be compared
    with an estimate in the same frame (001 §3.2, Figs. 10 and 13). mm.
    """
    p = np.asarray(points_mm, dtype=float)
    c = np.asarray(commands_mm, dtype=float)
    centre = c.mean(axis=0)
    rel = c - centre
    angle, shift = 0.0, np.zeros(2)
    for _ in range(5):  # the rotation's condition is nonlinear in the angle: a few Newton steps
        R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        q = (p - centre) @ R.T + centre
        shift = -(q - c).mean(axis=0)
        e = q + shift - c
        moment = np.sum(rel[:, 0] * e[:, 1] - rel[:, 1] * e[:, 0])
        d_moment = np.sum(rel[:, 0] * (q[:, 0] - centre[0]) + rel[:, 1] * (q[:, 1] - centre[1]))
        angle -= moment / d_moment
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = [(np.asarray(a, dtype=float) - centre) @ R.T + centre + shift for a in (p,) + others_mm]
    return moved[0] if not others_mm else tuple(moved)


def multilaterate(data: MachineCampaign, options: MultilaterationOptions = None, budget=None) -> MultilaterationResult:
    """Self-calibrating multilateration of a machine-tool campaign (001 Eq. 2-6); see :meth:`Multilateration.solve`."""
    return Multilateration(data, options).solve(budget)
