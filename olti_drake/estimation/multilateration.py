"""Self-calibrating multilateration of paper 001 §2.3 (Eq. 2-6), on the one calibration program,
in D = 2 dimensions (the paper's table) or D = 3 (the machine tool in 3D, formats.md).

:class:`Multilateration` is :class:`~olti_drake.estimation.calibration.Calibration` over the free points of 001
(:class:`olti_drake.model.free_points.FreePoints`), the shared distance measurement
(:class:`olti_drake.model.measurements.StationDistanceMeasurement`, 001 Eq. 3) and a named gauge
(:func:`olti_drake.model.gauges.free_points_gauge`); this module adds the campaign reader, the counting and
geometry checks, the start (001 §2.3) and the result.

Unknowns (Eq. 4): the target positions p_i ∈ R^D, the station (rotary-table or
pan/tilt-head interferometer) positions P_j ∈ R^D and the dead paths L0_j;
readings ΔL_ij = ‖p_i − P_j‖ − L0_j (Eq. 3). Distances cannot see where the
frame is: D translations and D(D − 1)/2 rotations (3 in 2D; 001's six
constraints in 3D) are fixed explicitly as linear constraints and stated in
the result's ``gauge``.

Counting: D·N_i + (D + 1)·N_j − D(D + 1)/2 unknowns against N_i·N_j readings, so
N_i > ((D + 1)N_j − D(D + 1)/2)/(N_j − D) with N_j ≥ D + 1: in 2D
N_i > (3N_j − 3)/(N_j − 2), in 3D 001's N_i > (4N_j − 6)/(N_j − 3).

Degenerate geometry is refused by name before solving: targets whose
positions lie on one line (2D) or plane (3D) -- the stations' mirror images
through it give the same readings, and a station fit from them is ambiguous;
stations on one line (2D) or plane (3D) -- the Jacobian loses rank beyond the
gauge (a target's offset across the station plane trades against the dead
paths to first order). What is left singular is caught by the rank check.

Several reflector mountings on the spindle (``tool`` column, 3D) make target i
the point command_i + t_tool(i); the nominal offsets t are given, or
estimated from the data relative to tool 0 (then stated in the notes).

Units: mm.
"""

import os
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import MULTILATERATION_RESULT as FORMAT
from olti_drake.io.csvio import (check_finite, check_indices, check_no_duplicate_rows, check_spread, check_values,
                                 json_numbers, read_json, read_table)
from olti_drake.model.free_points import FreePoints, fit_tool_offsets
from olti_drake.model.gauges import GAUGES, GAUGES_BY_DIM  # noqa: F401 (re-exported)
from olti_drake.model.gauges import check_gauge_kind, free_points_gauge, gauge_rows
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.estimation.calibration import station_fit  # noqa: F401 (station_fit re-exported)
from olti_drake.estimation.calibration import Calibration, SolverOptions, StationFitFailed, UnidentifiableError
from olti_drake.threads import single_thread_blas

REQUIRED = ("station", "target", "x_cmd_mm", "y_cmd_mm", "displacement_mm")
#: The command columns of a D-dimensional campaign: the first D of these (3D when ``z_cmd_mm`` is present).
COMMAND_COLUMNS = ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm")
#: The gauges of each dimension (``GAUGES_BY_DIM``; ``GAUGES`` is every name): :mod:`olti_drake.model.gauges`.


@dataclass(frozen=True)
class MachineCampaign:
    """Valid readings of a machine-tool campaign (formats.md): station j, target i, ΔL_ij (mm).

    ``commands_mm`` (N_i, D) is the command position p*_i of every target index (D = 3 when the file has
    ``z_cmd_mm``); ``tool`` (N_i,) the reflector mounting index of every target (default 0).
    """

    station: np.ndarray
    target: np.ndarray
    commands_mm: np.ndarray
    displacement_mm: np.ndarray
    line: np.ndarray
    source: str = ""
    tool: Optional[np.ndarray] = None

    def __post_init__(self):
        if self.tool is None:
            object.__setattr__(self, "tool", np.zeros(len(self.commands_mm), dtype=int))

    @property
    def dim(self) -> int:
        """2 (001's table) or 3 (the machine tool in 3D)."""
        return int(self.commands_mm.shape[1])

    @property
    def n_tools(self) -> int:
        return int(self.tool.max()) + 1

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
    carry the same command position (and tool) on every row. 3D when the file
    has ``z_cmd_mm``; ``tool`` optional (default 0).
    """
    return machine_campaign(read_table(path, REQUIRED, ("z_cmd_mm", "tool", "valid"),
                                       integer=("station", "target", "tool", "valid")), os.fspath(path))


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
    D = 3 if "z_cmd_mm" in t else 2
    check_finite(t, source, REQUIRED + COMMAND_COLUMNS[2:D])
    i, j = check_indices(t, source, "target"), check_indices(t, source, "station")
    tool = check_indices(t, source, "tool") if "tool" in t else np.zeros(len(i), dtype=int)
    xy = np.column_stack([t[c] for c in COMMAND_COLUMNS[:D]])
    cmd, tools = _per_target(i, xy, tool, t["_line"], source)
    size = np.hypot.reduce(np.ptp(cmd, axis=0))
    check_spread(t["displacement_mm"], j, t["_line"], source, "displacement_mm", 1.5 * size + 10.0, "station",
                 f"the {size:g} mm diagonal of the commands, with a margin")
    return MachineCampaign(j, i, cmd, t["displacement_mm"], t["_line"], source, tools)


def _per_target(i, xy, tool, lines, source):
    """Command (N_i, D) and tool (N_i,) of every target index, from its first row; a row that disagrees
    with that first row is refused naming both lines (a target index names one command and one tool)."""
    first = np.full(i.max() + 1, -1)
    first[i[::-1]] = np.arange(len(i))[::-1]  # the first row of a target defines its command and tool
    cmd, tools = xy[first], tool[first]
    clash = np.flatnonzero(np.any(np.abs(cmd[i] - xy) > 1e-9, axis=1) | (tools[i] != tool))
    if clash.size:
        k = clash[0]
        k0 = first[i[k]]

        def says(r):
            return "(" + ", ".join(f"{v:g}" for v in xy[r]) + ") mm" + (f", tool {tool[r]}" if tool.any() else "")

        raise InputError(f"{source}:{lines[k]}: target {i[k]} has command {says(k)}, but {says(k0)} on line "
                         f"{lines[k0]} (a target index names one command position and tool)")
    return cmd, tools


@dataclass
class MultilaterationOptions(SolverOptions):
    """Solver options plus: initial station positions (mm, e.g. from the rotation-centre
    estimate of 001 §2.2), the gauge (``best-fit``: the estimated targets have no mean
    translation or rotation from their nominal positions; ``first-two`` (2D): target 0 at its
    command, target 1 on the line of its command direction; ``first-three`` (3D): target 0 at its
    command, target 1 on that line, target 2 in the plane of the first three commands), and the
    nominal tool offsets (M, D) mm of the campaign's tool indices (default: zero for one tool,
    estimated relative to tool 0 for several)."""

    stations_mm: Optional[np.ndarray] = None
    gauge: str = "best-fit"
    tool_offsets_mm: Optional[np.ndarray] = None


@dataclass
class MultilaterationResult:
    """Estimated targets (N_i, D), stations (N_j, D), dead paths (N_j,) mm, uncertainties (k = 1)."""

    targets_mm: np.ndarray
    stations_mm: np.ndarray
    dead_paths_mm: np.ndarray
    targets_std_mm: np.ndarray
    fit: object
    gauge: str
    commands_mm: np.ndarray = field(default=None)
    gauge_kind: str = "best-fit"
    #: The campaign solved from: {"readings": N, "sha256": ...} (:func:`csvio.campaign_digest`).
    campaign: dict = field(default_factory=dict)
    #: Tool index of every target and the nominal tool offsets used (3D campaigns), mm.
    tools: Optional[np.ndarray] = None
    tool_offsets_mm: Optional[np.ndarray] = None

    @property
    def residual_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.fit.residuals ** 2)))

    @property
    def dim(self) -> int:
        return int(self.targets_mm.shape[1])

    @property
    def nominal_mm(self) -> np.ndarray:
        """Nominal target positions: commands plus their tools' nominal offsets, mm."""
        if self.tool_offsets_mm is None:
            return self.commands_mm
        return self.commands_mm + self.tool_offsets_mm[self.tools]

    def to_dict(self) -> dict:
        """The machine-tool ``result.json`` of formats.md (2D, or 3D with ``tools`` and ``tool_offsets_mm``): the
        targets, stations, dead paths and gauge kind of 001, the common fields by the one codec
        (:func:`olti_drake.io.documents.result_document`)."""
        from olti_drake.io import documents

        f = self.fit
        n_i, n_j, D = len(self.targets_mm), len(self.stations_mm), self.dim
        std = f.std
        tools = {} if self.tool_offsets_mm is None else {"tools": self.tools.tolist(),
                                                          "tool_offsets_mm": self.tool_offsets_mm.tolist()}
        values = {"targets_mm": self.targets_mm.tolist(), "stations_mm": self.stations_mm.tolist(),
                  "dead_paths_mm": self.dead_paths_mm.tolist(), "gauge_kind": self.gauge_kind,
                  "commands_mm": self.commands_mm.tolist(), **tools}
        unc = {"targets_mm": self.targets_std_mm.tolist(),
               "stations_mm": std[D * n_i:D * n_i + D * n_j].reshape(-1, D).tolist(),
               "dead_paths_mm": std[D * n_i + D * n_j:].tolist()}
        method = "linear propagation (JCGM 100): " + (
            "of the budget" if any("budget" in n for n in f.notes) else "of the residual variance")
        return documents.result_document("multilateration", values, f, gauge=self.gauge, uncertainty=unc,
                                         method=method, campaign=self.campaign)


def counting_bound(n_stations: int, dim: int) -> float:
    """The fewest targets N_i must exceed (001 Eq. 4 counting): unknowns D N_i + (D + 1) N_j − D(D + 1)/2
    (targets, stations with their dead paths, less the gauge) below the N_i N_j readings, so
    N_i > ((D + 1) N_j − D(D + 1)/2)/(N_j − D); 2D (3 N_j − 3)/(N_j − 2), 3D (4 N_j − 6)/(N_j − 3).
    Needs N_j > D (infinite otherwise)."""
    if n_stations <= dim:
        return float("inf")
    return ((dim + 1) * n_stations - dim * (dim + 1) / 2) / (n_stations - dim)


def affine_rank(points, rel_tol: float = 1e-9) -> int:
    """Dimension of the affine hull of ``points`` (K, D): 0 one point, 1 a line, 2 a plane, 3 a volume."""
    p = np.asarray(points, dtype=float)
    if len(p) < 2:
        return 0
    return int(np.linalg.matrix_rank(p - p.mean(axis=0), tol=rel_tol * max(1.0, float(np.abs(p).max()))))


def _flat_name(dim: int) -> str:
    return "line" if dim == 2 else "plane"


class Multilateration(Calibration):
    """The self-calibrating multilateration problem (001 Eq. 2-6) as a Drake MathematicalProgram, 2D or 3D: the
    one :class:`~olti_drake.estimation.calibration.Calibration` over the free points of 001
    (:class:`~olti_drake.model.free_points.FreePoints`: the targets p_i, at the commands plus the tool offsets to
    start), read by the shared distance measurement
    (:class:`~olti_drake.model.measurements.StationDistanceMeasurement`: stations P_j, dead paths L0_j, 001 Eq. 3)
    with a named gauge of :mod:`olti_drake.model.gauges` (``options.gauge``).

    What is the multilateration's own stays here: the counting (001 Eq. 4) and geometry checks before the
    program is built, the start (tool offsets relative to tool 0, stations from the nominal targets, 001 §2.3),
    the messages' hints and :meth:`solve` into a :class:`MultilaterationResult`.

    Variables ``p{i}_x_mm``, ``p{i}_y_mm`` (, ``p{i}_z_mm``), ``P{j}_x_mm`` … , ``L0_{j}_mm``. The Jacobian
    is sparse (a reading touches one target and one station): :meth:`residuals` returns it as CSR. Units: mm.
    """

    budget_kind = "machine"  # (000 Table 2 / 001 Table 4: Calibration.default_budget)
    reading_keys = ("line", "station", "target")  # (Calibration.reading_label)

    rank_hint = "check the station layout: stations on one line with the targets cannot locate them"
    untouched_hint = "every target needs readings from the stations"

    #: A station farther than this many command spans from the command centroid is absurd
    #: (:attr:`StationDistanceMeasurement.STATION_SPANS`).
    STATION_SPANS = StationDistanceMeasurement.STATION_SPANS
    #: A target estimated farther than this fraction of the command span from its command is absurd
    #: (:attr:`FreePoints.TARGET_SPAN_FRACTION`).
    TARGET_SPAN_FRACTION = FreePoints.TARGET_SPAN_FRACTION
    #: Stations whose extent across their best line (2D) or plane (3D) is below this fraction of their
    #: extent along it are on it (singular values of the centred positions).
    FLAT_STATIONS = 1e-4

    def __init__(self, data: MachineCampaign, options: MultilaterationOptions = None):
        o = options or MultilaterationOptions()
        check_gauge_kind(o.gauge, data.dim)
        self.data = data
        self.dim = data.dim
        self._check_counts()
        self._check_geometry_of_targets()
        notes = []
        self.tool_offsets_mm = self._tool_offsets(o, notes)
        self.model = FreePoints(data.commands_mm, data.tool, self.tool_offsets_mm)  # the position model
        self.nominal_mm = self.model.nominal_mm
        stations, dead_paths = self._start_stations(o)
        measurement = StationDistanceMeasurement(self.model, data.target, data.station, data.displacement_mm,
                                                 stations, dead_paths, data.n_stations, dead_path="L0")
        self.measurement = measurement
        self._check_geometry_of_stations(measurement.start_vector())
        gauge = free_points_gauge(o.gauge, self.nominal_mm, len(measurement.names))
        super().__init__(measurement, o, gauge, data.source or "campaign")
        self.notes.extend(notes)

    def _split(self, x):
        """(targets (N_i, D), stations (N_j, D), dead paths (N_j,)) of a parameter vector."""
        xm, stations, dead = self.measurement.split(x)
        return xm.reshape(-1, self.dim), stations, dead

    def _check_counts(self):
        d, D = self.data, self.dim
        n_i, n_j = d.n_targets, d.n_stations
        gauge = D * (D + 1) // 2
        if n_j < D + 1:
            raise UnidentifiableError(
                f"{d.source}: {n_j} station position(s); {D}D self-calibrating multilateration needs at least "
                f"{D + 1} (each target has {D} unknowns and each station {D + 1}, less the {gauge} of the gauge) -- "
                f"the stations and dead paths are not identifiable", [f"P{j}" for j in range(n_j)])
        need = counting_bound(n_j, D)
        if not n_i > need:
            form = "(3 N_j - 3)/(N_j - 2)" if D == 2 else "(4 N_j - 6)/(N_j - 3)"
            raise UnidentifiableError(
                f"{d.source}: {n_i} targets with {n_j} stations; {D}D needs N_i > {form} = {need:g} "
                f"(unknowns {D} N_i + {D + 1} N_j - {gauge} against N_i N_j readings; 001 Eq. (4))")
        seen = np.zeros((n_i, n_j), dtype=bool)
        seen[d.target, d.station] = True
        lonely = np.flatnonzero(seen.sum(axis=1) < D)
        if lonely.size:
            raise UnidentifiableError(f"{d.source}: target {lonely[0]} is read from {seen[lonely[0]].sum()} station(s); "
                                      f"a {D}D position needs at least {D} (and redundancy more)",
                                      [f"p{lonely[0]}_{c}_mm" for c in "xyz"[:D]])
        few = np.flatnonzero(seen.sum(axis=0) < D + 2)
        if few.size:
            j = int(few[0])
            raise UnidentifiableError(f"{d.source}: station {j} reads {seen[:, j].sum()} target(s); its position and "
                                      f"dead path ({D + 1} unknowns) need at least {D + 2}",
                                      [f"P{j}_{c}_mm" for c in "xyz"[:D]] + [f"L0_{j}_mm"])

    def _check_geometry_of_targets(self):
        """Refuse targets whose commands span less than the space: on one line (2D) or one plane (3D)."""
        d, D = self.data, self.dim
        if affine_rank(d.commands_mm) < D:
            flat = _flat_name(D)
            raise UnidentifiableError(
                f"{d.source}: not identifiable: P0..P{d.n_stations - 1} -- the {d.n_targets} target command "
                f"positions lie on one {flat}: the stations' mirror images through it explain every reading "
                f"alike (spread the targets over the {'plane' if D == 2 else 'volume'})",
                [f"P{j}_{c}_mm" for j in range(d.n_stations) for c in "xyz"[:D]])

    def _check_geometry_of_stations(self, x):
        """Refuse stations (as first estimated) on one line (2D) or one plane (3D): the Jacobian loses rank
        beyond the gauge (found numerically; the condition number is infinite)."""
        d, D = self.data, self.dim
        _, stations, _ = self._split(x)
        spread = np.linalg.svd(stations - stations.mean(axis=0), compute_uv=False)
        # Within 1e-4 of the layout's extent of a line/plane (0.1 mm over a metre): the start estimates carry
        # µm of noise, and the fit would be rank deficient to that level.
        if len(spread) < D or spread[D - 1] < self.FLAT_STATIONS * spread[0]:
            flat = _flat_name(D)
            raise UnidentifiableError(
                f"{d.source}: not identifiable: P0..P{d.n_stations - 1} -- the {d.n_stations} stations lie on one "
                f"{flat}: a target's offset across it trades against the dead paths (rank deficient beyond the "
                f"gauge; raise or lower {'one station off the line' if D == 2 else 'one or two heads off the plane'})",
                [f"P{j}_{c}_mm" for j in range(d.n_stations) for c in "xyz"[:D]])

    def _station_fits(self, points_mm, rows, S=None):
        """(P_j, L0_j) of every station from known points (N_i, D) at the readings ``rows`` (bool mask)."""
        d, D = self.data, self.dim
        fits = []
        for j in range(d.n_stations):
            sel = rows & (d.station == j)
            try:
                fits.append(station_fit(points_mm[d.target[sel]], d.displacement_mm[sel], None if S is None else S[j]))
            except StationFitFailed as e:  # the points spread: the readings are at fault, not the layout
                raise InputError(f"{d.source}: station {j}: {e}") from None
            except ValueError as e:
                names = [f"P{j}_{c}_mm" for c in "xyz"[:D]]
                raise UnidentifiableError(f"{d.source}: station {j}: not identifiable: {', '.join(names)} -- the "
                                          f"targets it reads lie on one {_flat_name(D)} ({e})", names) from None
        return fits

    def _tool_offsets(self, o: MultilaterationOptions, notes: list):
        """Nominal tool offsets (M, D) mm: given, zero for a one-tool 3D campaign, estimated for several (relative
        to tool 0: stations from tool 0's targets at their commands, then each tool's common offset by
        Gauss-Newton on its readings, :func:`~olti_drake.model.free_points.fit_tool_offsets`; said in
        ``notes``); None for a 2D campaign without tools (the 2D result is unchanged)."""
        d, D = self.data, self.dim
        if o.tool_offsets_mm is not None:
            t = np.asarray(o.tool_offsets_mm, dtype=float).reshape(-1, D)
            if len(t) < d.n_tools:
                raise InputError(f"tool_offsets_mm gives {len(t)} offset(s) but the campaign uses tools "
                                 f"0..{d.n_tools - 1}")
            return t
        if d.n_tools == 1:
            return None if D == 2 else np.zeros((1, D))
        fits = self._station_fits(d.commands_mm, d.tool[d.target] == 0)
        t = fit_tool_offsets(d.commands_mm, d.tool, d.target, d.station, d.displacement_mm,
                             np.array([f[0] for f in fits]), np.array([f[1] for f in fits]), d.n_tools)
        notes.append("tool offsets estimated from the data relative to tool 0 (mm): "
                     + "; ".join(",".join(f"{v:.4f}" for v in row) for row in t))
        return t

    def _start_stations(self, o: MultilaterationOptions):
        """Stations (N_j, D) and dead paths (N_j,) mm to start: fitted to the targets at their nominal positions
        (001 §2.3: the commands plus the tool offsets), from the given estimates ``o.stations_mm`` when there
        are (e.g. the rotation-centre estimates of 001 §2.2)."""
        d, D = self.data, self.dim
        S = None if o.stations_mm is None else np.asarray(o.stations_mm, dtype=float).reshape(-1, D)
        if S is not None and len(S) != d.n_stations:
            raise InputError(f"stations_mm gives {len(S)} positions but the campaign has {d.n_stations} stations")
        fits = self._station_fits(self.nominal_mm, np.ones(len(d), dtype=bool), S)
        return np.array([f[0] for f in fits]).reshape(-1, D), np.array([f[1] for f in fits])

    def solve(self, budget=None) -> MultilaterationResult:
        """Check counts and geometry, solve Eq. (2) of 001, and propagate the uncertainty.

        With a ``budget`` (e.g. 001 Table 4) the standard uncertainties are its
        linear propagation (JCGM 100) -- with few redundant readings (3
        stations: N_i − 6 degrees of freedom) the residuals alone estimate the
        reading noise poorly; without one, the residual-based propagation.
        """
        from olti_drake.io.csvio import campaign_digest

        self._solve_budget = budget
        # One BLAS thread: on the shared 2-core machine OpenBLAS threads made the 1820-unknown 3D solve
        # (benchmarks/bench_multilateration3d.py) 59 s against 18 s, both under a load of 8.
        with single_thread_blas():
            f = self.fit()
            if budget is not None:
                from olti_drake.estimation.uncertainty import linear_covariance  # builds on this layer
                from olti_drake.model.budget import ReadingErrors

                f.covariance = linear_covariance(self, f.x, ReadingErrors(budget))
                f.std = np.sqrt(np.maximum(np.diag(f.covariance), 0))
                f.notes.append(f"uncertainty: linear propagation of the budget '{budget.name}'")
        targets, stations, dead = self._split(f.x)
        return MultilaterationResult(targets, stations, dead, self._split(f.std)[0], f, self.gauge,
                                     self.data.commands_mm, self.options.gauge, campaign_digest(self.data),
                                     None if self.tool_offsets_mm is None else self.data.tool,
                                     self.tool_offsets_mm)


def _gauge_rows(kind: str, c, n: int):
    """(A, b, sentence) of the gauge over n parameters whose first D N_i are the targets, from the nominal
    target positions c (N_i, D) mm (:func:`olti_drake.model.gauges.gauge_rows`)."""
    return gauge_rows(kind, c, n)


def load_result(path) -> dict:
    """Read a machine-tool result.json (formats.md), its schema checked where it is read: targets N x D
    (D = 2, or 3 for a 3D campaign), stations M x D and dead paths M (mm; commands N x D and standard
    uncertainties of the same shapes, >= 0, when present; 3D: ``tools`` N and ``tool_offsets_mm``), every
    number finite and within +-1e5 mm, ``gauge`` a sentence; a SCARA result or a campaign is refused by its
    ``format``. Errors are one line naming the file and the key."""
    name = os.fspath(path)
    data = read_json(path, FORMAT, "a machine-tool result (olti multilaterate)")
    width = np.shape(data.get("targets_mm"))[1:2]
    D = 3 if width == (3,) else 2
    T = json_numbers(data, name, "targets_mm", (None, D))
    S = json_numbers(data, name, "stations_mm", (None, D))
    json_numbers(data, name, "dead_paths_mm", (len(S),))
    if "commands_mm" in data:
        json_numbers(data, name, "commands_mm", T.shape)
    if "tool_offsets_mm" in data:
        json_numbers(data, name, "tool_offsets_mm", (None, D))
        tools = np.asarray(data.get("tools"))
        if tools.shape != (len(T),) or not np.issubdtype(tools.dtype, np.integer) or np.any(tools < 0) \
                or np.any(tools >= len(data["tool_offsets_mm"])):
            raise InputError(f"{name}: key 'tools': expected {len(T)} tool indices into tool_offsets_mm")
    if not isinstance(data.get("gauge"), str):
        raise InputError(f"{name}: key 'gauge': expected the sentence stating the gauge, got {data.get('gauge')!r}")
    unc = data.get("uncertainty")
    for key, shape in (("targets_mm", T.shape), ("stations_mm", S.shape), ("dead_paths_mm", (len(S),))):
        if isinstance(unc, dict) and key in unc:
            if np.any(json_numbers(unc, name, key, shape, label=f"uncertainty.{key}") < 0):
                raise InputError(f"{name}: key 'uncertainty.{key}': a standard uncertainty is < 0")
    data.setdefault("gauge_kind", "first-two" if "target 0" in data["gauge"] else "best-fit")
    if data["gauge_kind"] not in GAUGES_BY_DIM[D]:
        raise InputError(f"{name}: key 'gauge_kind' must be one of {', '.join(GAUGES_BY_DIM[D])}, "
                         f"got {data['gauge_kind']!r}")
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
    if c.shape[1] == 3:
        return _align_3d(p, c, others_mm)
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


def _rodrigues(w) -> np.ndarray:
    """Rotation matrix of the rotation vector w (rad)."""
    angle = np.linalg.norm(w)
    if angle == 0:
        return np.eye(3)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _align_3d(p, c, others):
    """The 3D best-fit gauge of :func:`align_to_commands`: Newton on the rotation vector (the moment
    Σ rel × e is nonlinear in it), the translation then exact."""
    centre = c.mean(axis=0)
    rel = c - centre

    def moved(w, a):
        q = (np.asarray(a, dtype=float) - centre) @ _rodrigues(w).T + centre
        return q

    def moment(w):
        q = moved(w, p)
        e = q - (q - c).mean(axis=0) - c
        return np.cross(rel, e).sum(axis=0)

    w = np.zeros(3)
    for _ in range(8):
        m = moment(w)
        J = np.column_stack([(moment(w + 1e-7 * np.eye(3)[k]) - m) / 1e-7 for k in range(3)])
        w = w - np.linalg.solve(J, m)
    shift = -(moved(w, p) - c).mean(axis=0)
    out = [moved(w, a) + shift for a in (p,) + tuple(others)]
    return out[0] if not others else tuple(out)


def multilaterate(data: MachineCampaign, options: MultilaterationOptions = None, budget=None) -> MultilaterationResult:
    """Self-calibrating multilateration of a machine-tool campaign (001 Eq. 2-6); see :meth:`Multilateration.solve`."""
    return Multilateration(data, options).solve(budget)
