"""Identification of the 21 ISO 230-1 error motions of a 3-axis machine from a distance campaign.

Paper 001 measures a machine tool by self-calibrating multilateration (Eq. 2-6):
readings ΔL_ij = ‖p_i − P_j‖ − L0_j (Eq. 3) from stations P_j with dead paths
L0_j. Here the target positions p_i are not free points but the volumetric
model of :mod:`olti_drake.model.volumetric3d` (docs/machine_3d.md) at target
i's command and tool: p_i = p(q_i, t_m; θ). Unknowns:

* θ: the B-spline coefficients of the 18 axis error motions and the 3
  squareness errors (mm, µrad), minus the motions the campaign cannot separate
  (held at 0 and reported by name, :func:`separable_motions`);
* the offset errors of tools 1, 2, … (mm; tool 0's offset is the origin and is
  taken as given, so are all offsets in a 1-tool campaign);
* the station positions P_j (3D, mm) and dead paths L0_j (mm).

Residual r_k = ‖p(q_i, t_m; θ) − P_j‖ − L0_j − ΔL_k (mm, 001 Eq. (3)), analytic Jacobian.

The one engine: :class:`VolumetricIdentification` is
:class:`~olti_drake.estimation.calibration.Calibration` over the volumetric
position model (:class:`olti_drake.model.volumetric3d.VolumetricPositionModel`:
the tool points of the targets, the held motions taken out), read by the shared
distance measurement (:class:`olti_drake.model.measurements.StationDistanceMeasurement`,
001 Eq. (3)), with the representation's gauge
(:func:`olti_drake.model.gauges.volumetric_gauge`). What is the volumetric
machine's own stays here: the machine of the campaign (travel, knots, tools),
the counting, the station start, the observability rules that decide which
motions are held (:func:`separable_motions`) and :meth:`~VolumetricIdentification.solve`
into a :class:`VolumetricResult`.

Gauge: distances see neither a translation nor a rotation of the whole
(machine + stations); the representation fixes both, by the named conditions
of :data:`GAUGE_CONDITIONS` (the fixed B-spline coefficients are no unknowns):
the frame is the machine's own, origin at tool 0's point at the travel start,
x along X's reference straight line, y in the plane of X's and Y's lines.

Solved by :class:`~olti_drake.estimation.calibration.LeastSquaresProgram`
(LM, Drake programs; or NLP), refused when not converged; standard
uncertainties (k = 1) by linear propagation of the reading uncertainty of a
budget (JCGM 100; default 001 Table 4) through the identification, for every
motion value at the stated positions. Units: mm, µrad.
"""

from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import station_starts
from olti_drake.estimation.calibration import Calibration, SolverOptions, UnidentifiableError, smoothing_on
from olti_drake.estimation.multilateration import MachineCampaign
from olti_drake.estimation.uncertainty import trial_tolerance
from olti_drake.estimation.resolution import Finer, inflate, resolution_check as compare_representations
from olti_drake.io.csvio import campaign_digest
from olti_drake.model.gauges import VOLUMETRIC_GAUGE, VOLUMETRIC_GAUGE_CONDITIONS, volumetric_gauge
from olti_drake.model.measurements import StationDistanceMeasurement
# IMPLAUSIBLE_MM, IMPLAUSIBLE_URAD: the motion values no machine has (re-exported)
from olti_drake.model.volumetric3d import (ALL_MOTIONS, AXES, IMPLAUSIBLE_MM, IMPLAUSIBLE_URAD,  # noqa: F401
                                           MachineConfig, VolumetricModel, VolumetricPositionModel, motion_names,
                                           motion_role, motion_roughness, motion_unit, observability,
                                           roughness_lever_mm, check_table_sizes, TOPOLOGIES)

#: The conditions that fix the gauge (the frame), each by name; the fixed B-spline coefficients are no unknowns
#: (:data:`olti_drake.model.gauges.VOLUMETRIC_GAUGE_CONDITIONS`).
GAUGE_CONDITIONS = VOLUMETRIC_GAUGE_CONDITIONS
#: What the gauge fixes, in one sentence (:data:`olti_drake.model.gauges.VOLUMETRIC_GAUGE`).
GAUGE = VOLUMETRIC_GAUGE


def volumetric_campaign(data, source: str = ""):
    """The 3D machine campaign (``multilateration.MachineCampaign`` read with ``z_cmd_mm``: reading k is
    station ``station[k]`` reading target ``target[k]``; target i is command ``commands_mm[i]`` (x, y, z mm)
    with tool ``tool[i]``), checked for the volumetric model; one-line error when it has no z."""
    src = source or getattr(data, "source", "") or "campaign"
    c = np.asarray(data.commands_mm, float)
    if c.ndim != 2 or c.shape[1] != 3:
        raise InputError(f"{src}: the volumetric model needs 3D commands: column 'z_cmd_mm' is missing "
                         f"(formats.md, Machine tool in 3D)")
    if np.shape(data.tool) != (len(c),):
        raise InputError(f"{src}: one tool index per target expected, got {np.shape(data.tool)}")
    return data


@dataclass
class VolumetricOptions(SolverOptions):
    """Solver options plus the machine: ``tool_offsets_mm`` (one [x, y, z] per tool index, mm: tool 0's
    taken as given, the others' errors estimated; None: a 1-tool campaign at the spindle reference point),
    ``knot_spacing_mm`` (None: :func:`default_knot_spacing`, or :func:`smooth_knot_spacing` with the smoothness
    prior: ``smoothing`` 'auto' or a weight, the engine's :attr:`SolverOptions.smoothing`), ``topology`` (a key of :data:`TOPOLOGIES`),
    ``pitch_mm``: the stated positions of the motion values and their uncertainties."""

    tool_offsets_mm: Optional[Sequence[Sequence[float]]] = None
    knot_spacing_mm: Optional[float] = None
    topology: str = "serial"
    pitch_mm: float = 10.0
    #: The motions' smoothness prior (issue 23): 'off' (default: the knots alone, the resolution check guarding u),
    #: 'auto' (its weight by restricted maximum likelihood, on knots twice as fine as the commanded positions), or
    #: a weight.
    smoothing: object = "off"
    #: Run :meth:`VolumetricIdentification.resolution_check` after the solve (a second fit on finer knots; the
    #: stated u inflated when the two disagree beyond it).
    check_resolution: bool = True




def default_knot_spacing(commands_mm) -> float:
    """Knot spacing (mm) for the campaign's travel: per axis up to 8 intervals, but no more than the distinct
    command positions allow (a cubic spline with n intervals has n + 3 coefficients; at least 2 positions
    more than that); the largest such interval over the axes, rounded up to 0.1 mm."""
    c = np.asarray(commands_mm, float)
    spacing = 0.0
    for k in range(3):
        distinct = len(np.unique(np.round(c[:, k], 6)))
        n = int(np.clip(distinct - 5, 1, 8))
        spacing = max(spacing, float(np.ptp(c[:, k])) / n)
    return float(np.ceil(spacing * 10.0 - 1e-9) / 10.0)


#: The most knot intervals per axis the smoothed default gives (18 motions x 35 coefficients per axis at most).
SMOOTH_MAX_INTERVALS = 32


def smooth_knot_spacing(commands_mm) -> float:
    """Knot spacing (mm) with the smoothness prior: two intervals per step between distinct command positions
    (the prior, not the positions, then decides what the motions hold between them; measured on simulated
    campaigns, issue 23: finer knots change nothing more), at most :data:`SMOOTH_MAX_INTERVALS` per axis; the
    largest such interval over the axes, rounded up to 0.1 mm."""
    c = np.asarray(commands_mm, float)
    spacing = 0.0
    for k in range(3):
        distinct = len(np.unique(np.round(c[:, k], 6)))
        n = int(np.clip(2 * (distinct - 1), 1, SMOOTH_MAX_INTERVALS))
        spacing = max(spacing, float(np.ptp(c[:, k])) / n)
    return float(np.ceil(spacing * 10.0 - 1e-9) / 10.0)


def start_tool_offsets(data: MachineCampaign) -> np.ndarray:
    """(M, 3) mm: tool offsets relative to tool 0 by the 3D self-calibrating multilateration of the same campaign
    (001 Eq. 2-6, tools estimated from the readings): the start when ``--tool-offsets-mm`` is not given."""
    from olti_drake.estimation.multilateration import multilaterate

    try:
        return np.asarray(multilaterate(data).tool_offsets_mm, float)
    except InputError as e:
        raise InputError(f"{data.source}: the campaign uses {data.n_tools} tools and no --tool-offsets-mm was given; "
                         f"estimating them by multilateration failed: {e}") from None


def machine_config(data: MachineCampaign, options: VolumetricOptions) -> MachineConfig:
    """The machine of the campaign: travel = the commanded range per axis, the options' tools and knots."""
    c = data.commands_mm
    for k, a in enumerate(AXES):
        if np.ptp(c[:, k]) <= 0:
            raise UnidentifiableError(f"{data.source}: every command has {a.lower()} = {c[0, k]:g} mm: the motions of "
                                      f"{a} ({', '.join(motion_names(a))}) are seen at one position only -- not "
                                      f"identifiable", list(motion_names(a)))
    tools = options.tool_offsets_mm
    if tools is None:
        tools = [[0.0, 0.0, 0.0]] if data.n_tools == 1 else start_tool_offsets(data)
    tools = np.asarray(tools, float)
    if tools.ndim != 2 or tools.shape[1] != 3 or len(tools) != data.n_tools:
        raise InputError(f"--tool-offsets-mm: {len(tools)} offset(s) given, but the campaign uses tool indices "
                         f"0..{data.n_tools - 1} (one 'x,y,z' per tool index, separated by ';')")
    if options.topology not in TOPOLOGIES:
        raise InputError(f"topology must be one of {', '.join(TOPOLOGIES)}, got {options.topology!r}")
    spacing = options.knot_spacing_mm or (smooth_knot_spacing(c) if smoothing_on(options)
                                          else default_knot_spacing(c))
    tool_chain, work_chain = TOPOLOGIES[options.topology]
    try:
        config = MachineConfig(tool_chain=tool_chain, work_chain=work_chain,
                               travel_mm={a: (float(c[:, k].min()), float(c[:, k].max())) for k, a in enumerate(AXES)},
                               knot_spacing_mm=float(spacing), tool_offsets_mm=tuple(map(tuple, tools)))
    except ValueError as e:
        raise InputError(f"{data.source}: {e}") from None
    check_table_sizes(config, options.pitch_mm)  # the result's motion tables, before any work
    if not smoothing_on(options):  # (with the smoothness prior, the prior holds what no position determines)
        _check_positions(data, config)
    return config



def _check_positions(data: MachineCampaign, config: MachineConfig) -> None:
    """Refuse, naming the axis, a spline richer than the campaign's positions along it: an angular motion
    has n_basis − 1 free coefficients (0 at the start), so the axis needs n_basis distinct positions --
    otherwise a combination of coefficients vanishing at every position is seen by no reading (this is
    the knot spacing's fault, not the tools', and is not held at 0 as a tool-geometry blind spot is)."""
    for k, a in enumerate(AXES):
        distinct = len(np.unique(np.round(data.commands_mm[:, k], 6)))
        need = config.n_basis(a)
        if distinct < need:
            intervals = need - 3
            raise UnidentifiableError(
                f"{data.source}: {a} is commanded at {distinct} distinct positions, but the cubic B-splines of its "
                f"motions ({', '.join(motion_names(a))}) have {need} coefficients ({intervals} knot interval(s) of "
                f"<= {config.knot_spacing_mm:g} mm) and need at least {need}: "
                + ("a cubic spline needs 4 -- add positions along " + a if need == 4 else
                   f"give a larger --knot-spacing-mm or more positions along {a}"), list(motion_names(a)))


def finer_knot_spacing(config: MachineConfig, commands_mm) -> Optional[float]:
    """The finest knot spacing in [s/2, s) (s: ``config.knot_spacing_mm``; rounded up to 0.1 mm) that changes the
    representation and whose splines the commanded positions still identify (every axis at no fewer distinct
    positions than its spline has coefficients, :func:`_check_positions`): the representation of the
    under-resolution check (:meth:`VolumetricIdentification.resolution_check`). None when there is none."""
    import dataclasses

    c = np.asarray(commands_mm, float)
    s = float(config.knot_spacing_mm)
    distinct = [len(np.unique(np.round(c[:, k], 6))) for k in range(3)]
    travel = [config.travel_mm[a][1] - config.travel_mm[a][0] for a in AXES]
    # The spacings where an axis' interval count changes (travel / n), and s/2 itself.
    candidates = {s / 2} | {t / n for t in travel for n in range(1, 2 * int(np.ceil(t / s)) + 2) if s / 2 <= t / n < s}
    now = [config.n_basis(a) for a in AXES]
    for v in sorted(float(np.ceil(v * 10.0 - 1e-9) / 10.0) for v in candidates):
        if not s / 2 - 1e-9 <= v < s - 1e-9:
            continue
        finer = dataclasses.replace(config, knot_spacing_mm=v)
        need = [finer.n_basis(a) for a in AXES]
        if need != now and all(n <= d for n, d in zip(need, distinct)):
            return v
    return None


def _priority(obs, name) -> tuple:
    """Which inseparable angular motion to hold first: none of the readings depends on it, then a roll (the
    rotation about the axis' own line, e.g. E_CZ about the spindle line), then ISO order."""
    return (obs.trades_with[name] != (), motion_role(name) != "roll", ALL_MOTIONS.index(name))


def separable_motions(model: VolumetricModel, commands_mm, tool, stations_mm,
                      prior=None) -> Tuple[Dict[str, str], object]:
    """The motions this campaign cannot separate, to hold at 0, with the note saying why; and the final
    :class:`~olti_drake.model.volumetric3d.MotionObservability` (all remaining separable).

    A calibration engineer keeps what the campaign determines and is told what it does not: inseparable
    *angular* motions are held at 0 one at a time (those no reading depends on all at once; then rolls
    first, then ISO order) until the rest separates -- the motions they traded with then carry their
    effect at the measured tool points. An inseparable linear motion, squareness or tool offset is not
    a matter of choice: it is refused (:class:`UnidentifiableError` naming them). ``prior``: the smoothness
    prior's rows over the model's parameters (:func:`~olti_drake.model.volumetric3d.motion_roughness`): what they
    determine (a motion's shape between the commanded positions) is separable; what they leave (its trend) is not.
    """
    held: Dict[str, str] = {}
    for _ in range(len(ALL_MOTIONS)):
        obs = observability(model, commands_mm, tool, stations_mm, held=tuple(held), prior=prior)
        angular = [n for n in obs.inseparable if n in ALL_MOTIONS and motion_unit(n) == "urad"]
        if not obs.inseparable:
            return held, obs
        if not angular:
            names = list(obs.inseparable)
            raise UnidentifiableError(
                "not identifiable: " + "; ".join(
                    f"{n} (trades with {', '.join(obs.trades_with[n]) or 'nothing: no reading depends on it'})"
                    for n in names) + " -- the campaign cannot separate them; add commands along that axis, tool "
                "offsets or stations" + (f" (already held at 0: {', '.join(held)})" if held else ""), names)
        pick = [n for n in angular if not obs.trades_with[n]] or [min(angular, key=lambda n: _priority(obs, n))]
        for n in pick:
            partners = [p for p in obs.trades_with[n] if p != "gauge"]
            held[n] = ("held at 0: no reading of this campaign depends on it" if not obs.trades_with[n] else
                       f"held at 0: this campaign cannot separate it from {', '.join(obs.trades_with[n])}"
                       + (f"; {', '.join(partners)} carry its effect at the measured tool points" if partners else ""))
    raise AssertionError("unreachable: every angular motion held")


class VolumetricIdentification(Calibration):
    """The distance residuals of a 3D campaign on the volumetric model, as a Drake MathematicalProgram: the one
    :class:`~olti_drake.estimation.calibration.Calibration` over
    :class:`~olti_drake.model.measurements.StationDistanceMeasurement` (001 Eq. (3): r_k = ‖p(q_i, t_m; θ) − P_j‖
    − L0_j − ΔL_k, mm) of the tool points of :class:`~olti_drake.model.volumetric3d.VolumetricPositionModel`,
    with the representation's gauge (:func:`~olti_drake.model.gauges.volumetric_gauge`: no constraint row).

    Variables: the free spline coefficients and squareness of the separable motions (names of
    ``VolumetricModel.parameter_names()``; mm, µrad), ``tool<m>_{x,y,z}_mm`` (m ≥ 1), ``P<j>_{x,y,z}_mm``,
    ``L0_<j>_mm``. Observability is checked at construction (before solving): the motions the campaign cannot
    separate are held at 0 (:attr:`held`, :func:`separable_motions`). :attr:`model` is the
    :class:`~olti_drake.model.volumetric3d.VolumetricModel` (all its parameters), :attr:`position_model` the
    position model of the campaign's targets (the free ones: :attr:`free_cols`, :attr:`n_model`).
    """

    budget_kind = "machine"  # (000 Table 2 / 001 Table 4: Calibration.default_budget)
    reading_keys = ("line", "station", "target")  # (Calibration.reading_label)

    rank_hint = "add stations, tool offsets or commands spread over the travel"
    untouched_hint = "every station needs readings of targets spread over the travel"
    #: The residuals beyond the readings' u are a model error every predicted tool point shares
    #: (:meth:`Calibration.lack_of_fit`): motions the splines between their knots do not follow.
    predicts_lack_of_fit = True

    def __init__(self, data: MachineCampaign, options: VolumetricOptions = None):
        o = options or VolumetricOptions()
        self.data = data
        self.config = machine_config(data, o)
        self.model = VolumetricModel(self.config, identify_tool_offsets=len(self.config.tools) > 1)
        self._check_counts()
        stations0, dead0 = self._station_start()
        prior = motion_roughness(self.model, roughness_lever_mm(data.commands_mm)) if smoothing_on(o) else None
        self.held, self.observability = self._separable(stations0, prior)
        self.position_model = VolumetricPositionModel(self.model, data.commands_mm, data.tool, held=tuple(self.held))
        self.free_cols = self.position_model.free_cols
        self.n_model = self.position_model.n_params
        measurement = StationDistanceMeasurement(self.position_model, data.target, data.station, data.displacement_mm,
                                                 stations0, dead0, data.n_stations, dead_path="L0")
        gauge = volumetric_gauge(len(measurement.names))
        # Fixed in the representation: no constraint row to add to the program (Calibration adds a gauge's rows).
        super().__init__(measurement, o, gauge if len(gauge.b) else None, data.source or "campaign")
        self.gauge = gauge.sentence
        # The Monte Carlo re-solves the volumetric trials one by one (on :meth:`residuals`), as it always has: its
        # batched chord iteration (on the measurement's ``residual_rows``) stops at a fixed 30 steps, short of the
        # tolerance on these µrad-scaled unknowns.
        self.__dict__.pop("residual_rows", None)
        self.notes.extend(f"{n}: {why}" for n, why in self.held.items())
        if o.tool_offsets_mm is None and data.n_tools > 1:
            self.notes.append("tool offsets not given (--tool-offsets-mm): started from the 3D multilateration's "
                              "estimate relative to tool 0: " + "; ".join(
                                  ",".join(f"{v:.4f}" for v in t) for t in self.config.tools) + " mm")

    @property
    def smoothing_subject(self) -> str:
        return (f"the error motions (the integral of each one's squared second derivative over its travel, an "
                f"angular motion's at a lever of {self.position_model.roughness_lever_mm():.4g} mm; knots every "
                f"{self.config.knot_spacing_mm:g} mm)")

    def implausible_cause(self, fit) -> str:
        """Given tool offsets that the readings' own estimate (the 3D multilateration's, as without
        ``--tool-offsets-mm``) contradicts by over 1 mm: the offsets, not the motions, are at fault."""
        given = self.options.tool_offsets_mm
        if given is None or self.data.n_tools < 2:
            return ""
        try:
            own = start_tool_offsets(self.data)
        except InputError:
            return ""
        given = np.asarray(given, float)
        off = float(np.abs(given - own).max()) if given.shape == own.shape else 0.0
        if off <= 1.0:
            return ""
        scale = float(np.linalg.norm(own[1:]) / max(np.linalg.norm(given[1:]), 1e-300))
        unit = f" (the readings' are {scale:.3g} x larger: in metres?)" if 500 < scale < 2000 else ""
        show = lambda t: "; ".join(",".join(f"{v:.4g}" for v in r) for r in t)  # noqa: E731
        return (f"the given --tool-offsets-mm {show(given)} differ by up to {off:.4g} mm from the offsets the readings "
                f"give, {show(own)} mm{unit}: give them in mm, or leave --tool-offsets-mm out (then they are estimated)")

    def _check_counts(self):
        # No station count: the targets are the model's tool points, not free points (001 Eq. (4), N_j > 3, is the
        # free points' rule); what fewer stations cannot separate is refused by name in :meth:`_separable`.
        d = self.data
        seen = np.zeros((len(d.commands_mm), d.n_stations), bool)
        seen[d.target, d.station] = True
        lonely = np.flatnonzero(~seen.any(axis=0))
        if lonely.size:
            raise UnidentifiableError(f"{d.source}: station {lonely[0]} has no valid reading",
                                      [f"P{lonely[0]}_x_mm"])

    def _separable(self, stations0, prior):
        """(held, observability): :func:`separable_motions` at the start stations; with fewer than 4 stations,
        only what even 3D tool points could not separate is held, and the campaign is refused by name when the
        readings leave more.

        Holding an inseparable motion at 0 is honest when its trade leaves the tool points unchanged (with 4
        stations or more every target point is fixed in 3D, 001 Eq. (4); then the motions it trades with carry
        its effect at the measured points). From 1-3 stations the readings fix only their lines of sight: a
        combination they cannot see may move the tool points across them, and holding it at 0 would leave
        its effect outside the stated u (measured, 3 tools, 600 random commands, truth of sines: 2 stations
        on the table, noise-free readings: unseen tool points off by RMS 2.3 um against a stated u of 1.2
        um; tests/estimation/test_volumetric_few_stations.py). So for them the motions are held as for 3D
        targets (:func:`separable_motions` without stations), and the distances (with the smoothness prior's
        rows, when on) must separate the rest."""
        d = self.data
        if d.n_stations >= 4:
            return separable_motions(self.model, d.commands_mm, d.tool, stations0, prior=prior)
        held, _ = separable_motions(self.model, d.commands_mm, d.tool, None, prior=prior)
        obs = observability(self.model, d.commands_mm, d.tool, stations0, held=tuple(held), prior=prior)
        if obs.inseparable:
            names = list(obs.inseparable)
            raise UnidentifiableError(
                f"{d.source}: from {d.n_stations} station(s) the readings cannot separate {', '.join(names)} "
                f"({obs.null_dimension} combination(s) of them move the tool points without changing a reading; "
                f"fewer than 4 stations fix no target point in 3D, 001 Eq. (4), so holding them at 0 would "
                f"leave their effect outside the stated u) -- add stations: 3 not on one line, or 4"
                + (f" (already held at 0, as for 3D targets: {', '.join(held)})" if held else ""), names)
        return held, obs

    def _station_start(self):
        """Per station, the 3D closed-form multilateration on the nominal tool points, refined (station_fit)."""
        d = self.data
        nominal = d.commands_mm + self.config.tools[d.tool]
        return station_starts(nominal[d.target], d.displacement_mm, d.station, range(d.n_stations), d.source)

    # -- the model ----------------------------------------------------------------------------------
    def theta(self, x) -> np.ndarray:
        """The model's full parameter vector (held motions 0) from the program's x."""
        return self.position_model.theta(x)

    def split(self, x):
        """(θ, stations (N_j, 3), dead paths (N_j,)) of x."""
        _, P, L0 = self.measurement.split(np.asarray(x, float))
        return self.theta(x), P, L0

    def residual_rows(self, X, displacement_mm=None):
        """001 Eq. (3) residuals of T parameter vectors at once, the Jacobian row-compressed
        (:meth:`~olti_drake.model.measurements.StationDistanceMeasurement.residual_rows`): the batched trials of
        :func:`~olti_drake.estimation.uncertainty.monte_carlo`. X (T, n), readings (K,) or (T, K) mm."""
        return self.measurement.residual_rows(X, displacement_mm)

    # -- solve ----------------------------------------------------------------------------------------
    def solve(self, budget=None) -> "VolumetricResult":
        """Solve, then the standard uncertainties (k = 1) by linear propagation of ``budget``'s reading
        uncertainty (default 001 Table 4) through the identification (JCGM 100)."""
        from olti_drake.estimation.uncertainty import ReadingErrors, linear_covariance
        from olti_drake.io.budget import default_budget

        budget = budget or default_budget("machine")
        self._solve_budget = budget
        f = self.fit()
        if f.smoothing is None:
            f.covariance = linear_covariance(self, f.x, ReadingErrors(budget))
            f.std = np.sqrt(np.maximum(np.diag(f.covariance), 0))
        # (smoothed: the fit's own posterior covariance σ² (JᵀJ + λP)⁻¹, σ not below the budget's reading u --
        # it holds the motions' error between their knots, which the sandwich of the budget alone does not; no
        # resolution check on its own fine knots (smooth_knot_spacing): the prior, not the knots, sets what the
        # motions can hold. On knots the user gave the knots may be too coarse whatever the prior: checked --
        # 400 mm knots on the tests' truth had 11 % of unseen tool points beyond 3 u unchecked)
        check = self.options.check_resolution and (f.smoothing is None or self.options.knot_spacing_mm is not None)
        resolution = self.resolution_check(f, budget) if check else None
        inflate(f, resolution)  # (too coarse for the data: the stated u made to cover what the finer knots show)
        E = np.zeros((self.model.n_params, len(self.names)))  # the model's parameters from x (held: 0)
        E[self.free_cols, np.arange(self.n_model)] = 1.0
        theta, P, L0 = self.split(f.x)
        n_j = self.data.n_stations
        return VolumetricResult(self.model, theta, E @ f.covariance @ E.T, P, L0,
                                f.std[self.n_model:self.n_model + 3 * n_j].reshape(n_j, 3),
                                f.std[self.n_model + 3 * n_j:], f, self.gauge, dict(self.held),
                                self.observability.describe(), campaign_digest(self.data),
                                f"linear propagation (JCGM 100) of the budget '{budget.name}'"
                                + (f", inflated {resolution['inflation']:.3g} x by the under-resolution check "
                                   f"(resolution_check)" if resolution and resolution.get("inflation", 1.0) > 1.0
                                   else ""),
                                self.options.pitch_mm, resolution=resolution)

    def resolution_check(self, fit, budget) -> Optional[dict]:
        """Does the representation hold what the data resolve? The engine's check
        (:func:`~olti_drake.estimation.resolution.resolution_check`) of the tool points at every target against
        the campaign identified again on the finest knots in [s/2, s) it can identify (:func:`finer_knot_spacing`;
        same tools, budget and gauge -- fixed in the representation, so both fits are in one frame). None when the
        campaign has no target to compare."""
        import dataclasses

        from olti_drake.model.propagation import predicted_std

        s = float(self.config.knot_spacing_mm)
        finer = Finer(this=f"<= {s:g} mm knots", extra={"knot_spacing_mm": s})
        own = (getattr(self, "_smoothing", None) or {}).get("binding")  # (the engine's prior: the refit has its own)
        users = [b for b in self._user_costs() if own is None or b.evaluator() is not own.evaluator()]
        f_s = finer_knot_spacing(self.config, self.data.commands_mm)
        if self.n_all > len(self.names) or self.prog.GetAllConstraints() or users:
            finer.why = ("the program carries the user's own variables, constraints or costs: a refit on other "
                         "knots cannot carry them")
        elif f_s is None:
            distinct = ", ".join(f"{a} {len(np.unique(np.round(self.data.commands_mm[:, k], 6)))}"
                                 for k, a in enumerate(AXES))
            finer.why = (f"no finer knot spacing in [{s / 2:g}, {s:g}) mm is identifiable from the commanded "
                         f"positions ({distinct} distinct): more positions along the axes would allow it")
        else:
            options = dataclasses.replace(self.options, knot_spacing_mm=f_s, check_resolution=False,
                                          tool_offsets_mm=[list(t) for t in self.config.tools])
            cmd, tool = self.data.commands_mm, self.data.tool

            def points():
                other = VolumetricIdentification(self.data, options).solve(budget)
                p_f, J_f = other.model.jacobian(cmd, tool, other.params)
                return p_f, predicted_std(J_f, other.covariance)
            finer.finer, finer.rerun, finer.points = f"<= {f_s:g} mm knots", f"--knot-spacing-mm {f_s:g}", points
            finer.extra["finer_knot_spacing_mm"] = f_s
        E = np.zeros((self.model.n_params, len(self.names)))
        E[self.free_cols, np.arange(self.n_model)] = 1.0
        p, J = self.model.jacobian(self.data.commands_mm, self.data.tool, self.split(fit.x)[0])
        return compare_representations(p, predicted_std(J, E @ fit.covariance @ E.T), finer)


@dataclass
class VolumetricResult:
    """The identified motions (θ, its covariance over ``model.parameter_names()``; held motions 0 with 0
    variance), stations (N_j, 3), dead paths (N_j,) mm and their standard uncertainties (k = 1), the fit."""

    model: VolumetricModel
    params: np.ndarray
    covariance: np.ndarray
    stations_mm: np.ndarray
    dead_paths_mm: np.ndarray
    stations_std_mm: np.ndarray
    dead_paths_std_mm: np.ndarray
    fit: object
    gauge: str
    held: Dict[str, str] = field(default_factory=dict)
    observability: str = ""
    campaign: dict = field(default_factory=dict)
    method: str = ""
    pitch_mm: float = 10.0
    #: The under-resolution check (:meth:`VolumetricIdentification.resolution_check`; the result's
    #: ``resolution_check``), None when not run.
    resolution: Optional[dict] = None

    @property
    def residual_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.fit.residuals ** 2)))

    def to_dict(self) -> dict:
        """The ``olti-volumetric/1`` result (formats.md; :func:`olti_drake.io.volumetric_io.volumetric_result_dict`:
        the common fields by the one codec, :func:`olti_drake.io.documents.result_document`)."""
        from olti_drake.io.volumetric_io import volumetric_result_dict

        return volumetric_result_dict(
            self.model, self.params, self.covariance, self.pitch_mm, self.fit, stations_mm=self.stations_mm,
            dead_paths_mm=self.dead_paths_mm, stations_std_mm=self.stations_std_mm,
            dead_paths_std_mm=self.dead_paths_std_mm, gauge=self.gauge, gauge_conditions=list(GAUGE_CONDITIONS),
            held=self.held, observability=self.observability, method=self.method, campaign=self.campaign)


def identify_volumetric(data: MachineCampaign, options: VolumetricOptions = None, budget=None) -> VolumetricResult:
    """Identify the 21 error motions from a 3D distance campaign (see the module docstring)."""
    return VolumetricIdentification(data, options).solve(budget)


#: The re-solved motion coefficients must reproduce the result's within this share of their u (else: not its
#: campaign, or other options).
REPRODUCE_U = 0.05


def result_options(doc: dict) -> VolumetricOptions:
    """The :class:`VolumetricOptions` of the identification that wrote the ``olti-volumetric/1`` result ``doc``:
    its topology, knots, pitch, the tools as given (the identified offsets less their identified errors) and its
    smoothness weight as given (or off)."""
    from olti_drake.model.volumetric3d import TOPOLOGIES

    chains = (tuple(doc["topology"]["tool_chain"]), tuple(doc["topology"]["work_chain"]))
    topology = next((k for k, v in TOPOLOGIES.items() if tuple(map(tuple, v)) == chains), None)
    if topology is None:
        raise InputError(f"volumetric result: topology {chains} is none of {', '.join(TOPOLOGIES)}")
    tools = np.asarray(doc["tool_offsets_mm"], float) - np.asarray(doc.get("tool_offset_errors_mm", 0.0), float)
    smoothing = doc.get("smoothing") or {}
    weight = smoothing.get("weight") if isinstance(smoothing, dict) else None
    return VolumetricOptions(tool_offsets_mm=tools.tolist(),
                             knot_spacing_mm=float(doc["representation"]["knot_spacing_mm"]), topology=topology,
                             pitch_mm=float(doc.get("pitch_mm", 10.0)),
                             smoothing=float(weight) if isinstance(weight, (int, float)) and weight > 0 else "off",
                             check_resolution=False)  # (the estimate is the same; the check only inflates the u)


def identification_at_result(res, data, budget):
    """(identification, its result): the volumetric result ``res`` (:class:`~olti_drake.io.volumetric_io.
    VolumetricDocument`) re-solved on ``data``, the campaign it came from (digest checked by the caller), with its
    options (:func:`result_options`). Refused in one line when the re-solved motions are not the result's."""
    ident = VolumetricIdentification(data, result_options(res.doc))
    solved = ident.solve(budget)
    names = list(res.model.parameter_names())
    motion = np.array([not n.startswith("tool") for n in names])  # (tool errors: relative to the tools as given)
    u = np.sqrt(np.maximum(np.diag(res.covariance), 0.0))
    z = np.abs(solved.params - res.params)[motion] / np.maximum(u[motion], 1e-12)
    if z.size and float(z.max()) > REPRODUCE_U:
        worst = np.asarray(names)[motion][int(np.argmax(z))]
        raise InputError(f"{res.source}: re-solved on its campaign, {worst} is {float(z.max()):.3g} u from the "
                         f"result's value (at most {REPRODUCE_U:g} u): not this campaign's result, or its options "
                         f"(loss, solver) were not the defaults")
    ident.trial_tolerance = trial_tolerance(solved.fit)  # (a millionth of each u: estimation.uncertainty)
    return ident, solved
