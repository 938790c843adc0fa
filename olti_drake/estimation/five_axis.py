"""Identification of a five-axis machine's location errors and rotary-axis error motions (issue 25, items 2, 3, 5).

The machine is read from its model file (:class:`~olti_drake.model.five_axis.FiveAxisMachine`), its errors by
ISO 230-1 / ISO 230-7 name (:class:`~olti_drake.model.five_axis_errors.FiveAxisErrors`): the location errors of
every rotary axis (mm, µrad) and, with ``model="errormap"``, its six error motions on a grid of the commanded
angle (paper 000's bidirectional map, Eq. 6-9, when the campaign has directions), plus the offset errors of tools
1, 2, … The campaign's readings (formats.md, "Five-axis machine tools") are what
:class:`~olti_drake.estimation.calibration.Calibration`, the one engine, solves:

* distances from stations (paper 001 Eq. (3): r = ‖p_i − P_j‖ − L0_j − ΔL), a station on the bed seeing the tool
  point in the base frame, one riding on the table in the workpiece frame;
* R-test / 3D-probe displacements from nests (ISO 10791-6 K4; r = p_i − c_n − d, each nest its own zero);
* tracker points (r = R p_i + t − m, one rigid frame per set-up, on the bed or on the table).

Each reading's tool point is in its own frame: :class:`FramedPositionModel` is one position model over the
error model whose point i is seen in the base or the workpiece frame, so that one
:class:`~olti_drake.model.displacements.CombinedMeasurement` holds a mixed campaign. Before solving, what the
campaign cannot separate (:func:`~olti_drake.model.five_axis_errors.separable`, on the measurement's own
Jacobian: stations, nests and frames as nuisance) is held at 0 and named with the reason; the error motions'
gauge (grid mean 0, no rotating first harmonic) is the model's. The maps' smoothness prior ('auto': its weight
by restricted maximum likelihood) as the robots'. Uncertainties: the engine's linear covariance (JCGM 100) plus,
for the maps, their representation on the grid (:meth:`FiveAxisIdentification.representation`: a Type B bubble
between nodes, its effect on every estimate and its share of a predicted point, ``Fit.lack_of_fit_mm``).
Units: mm, deg (commands), µrad.
"""

import dataclasses
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import scipy.sparse as sp

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import Calibration, SolverOptions, smoothing_on, station_starts
from olti_drake.model.five_axis_errors import FiveAxisErrors, FiveAxisPositionModel, separable
from olti_drake.model.volumetric3d import MotionJacobian

MODELS = ("geometric", "errormap")
#: ``FiveAxisOptions.linear`` words (anything else is a volumetric result's path). ``auto``: identified when the
#: campaign reads the tool point over the volume (distances, tracker points), perfect for an R-test campaign alone
#: (:func:`resolved_linear`).
LINEAR_AUTO, LINEAR_IDENTIFY, LINEAR_PERFECT = "auto", "identify", "perfect"
#: The words ``--linear`` takes (anything else is a volumetric result's file).
LINEAR_WORDS = (LINEAR_AUTO, LINEAR_IDENTIFY, LINEAR_PERFECT)
#: The reading uncertainty (mm, k = 1) each reading kind is weighed with in a mixed campaign (001 Table 4's
#: interferometer order; a tracker's 10 µm).
MIXED_SIGMAS_MM = {"distance": 0.001, "nest": 0.001, "tracker": 0.010}


@dataclass
class FiveAxisOptions(SolverOptions):
    """Solver options plus the error model: ``model`` geometric (location errors and tool offsets) | errormap (plus
    the error motions every ``pitch_deg`` of each rotary axis' travel); ``tool_offsets_mm`` one [x, y, z] per
    tool index in the tool frame (mm; default 0 for every tool: tool 0 is the reference, the others' errors are
    identified); ``smoothing`` the maps' prior ('auto' by default for errormap; geometric has no maps); ``linear``
    the linear axes: ``"identify"`` (formats.md: their 18 error motions and 3 squareness errors identified with
    the rotary axes, B-splines on knots every ``knot_spacing_mm``, None: :func:`linear_knot_spacing`), the path
    of an earlier ``olti-volumetric/1`` result whose motions are held fixed
    (:func:`~olti_drake.io.five_axis_io.load_linear_from`), ``"perfect"`` (None too: no linear-axis errors in the
    model), or ``"auto"`` (default: :func:`resolved_linear`)."""

    model: str = "errormap"
    pitch_deg: float = 15.0
    tool_offsets_mm: Optional[Sequence[Sequence[float]]] = None
    smoothing: object = "auto"
    linear: Optional[str] = LINEAR_AUTO
    knot_spacing_mm: Optional[float] = None


# ----------------------------------------------------------------------------------------------- the model
class FramedPositionModel:
    """The tool points of a five-axis campaign, point i in the frame ``frame[i]`` ('base': a station or tracker
    on the bed; 'workpiece': on the table, R-test): one position model over one error model (the
    :class:`FiveAxisPositionModel` of each frame, same parameters), for the engine's measurements. Everything
    but the points (names, gauge, roughness, layout, implausible values) is the error model's."""

    dim = 3

    def __init__(self, machine, error_model: FiveAxisErrors, commands, directions, tool, frame, held=()):
        frame = np.asarray(frame)
        self.frame = frame
        self.parts, self.index = {}, {}
        self.local = np.zeros(len(frame), int)
        for f in ("workpiece", "base"):
            idx = np.flatnonzero(frame == f)
            if not idx.size:
                continue
            d = None if directions is None else np.asarray(directions)[idx]
            self.parts[f] = FiveAxisPositionModel(machine, error_model, np.asarray(commands)[idx], d,
                                                  np.asarray(tool)[idx], frame=f, held=held)
            self.index[f] = idx
            self.local[idx] = np.arange(idx.size)
        self.first = next(iter(self.parts.values()))
        self.machine, self.errors, self.held = machine, error_model, tuple(held)
        self.free_cols, self.names = self.first.free_cols, self.first.names
        self.n_points = len(frame)

    @property
    def n_params(self) -> int:
        return self.first.n_params

    def start_vector(self) -> np.ndarray:
        return self.first.start_vector()

    def theta(self, x) -> np.ndarray:
        return self.first.theta(x)

    def positions(self, x=None) -> np.ndarray:
        out = np.zeros((self.n_points, 3))
        for f, pm in self.parts.items():
            out[self.index[f]] = pm.positions(x)
        return out

    def jacobian(self, x=None):
        """(N, 3) tool points and their :class:`MotionJacobian` (analytic, each frame's)."""
        p, cols, vals = np.zeros((self.n_points, 3)), None, None
        for f, pm in self.parts.items():
            pf, Jf = pm.jacobian(x)
            if cols is None:
                cols = np.zeros((self.n_points, Jf.cols.shape[1]), int)
                vals = np.zeros((self.n_points, 3, Jf.cols.shape[1]))
            p[self.index[f]], cols[self.index[f]], vals[self.index[f]] = pf, Jf.cols, Jf.vals
        return p, MotionJacobian(cols, vals, self.n_params)

    def rows(self, X, points):
        """Batched rows (:meth:`FiveAxisPositionModel.rows`) at ``points`` (K,), each from its frame's model."""
        points = np.asarray(points, int)
        X = np.atleast_2d(np.asarray(X, float))
        T, K = X.shape[0], points.size
        p = cols = dp = None
        for f, pm in self.parts.items():
            sel = np.flatnonzero(self.frame[points] == f)
            if not sel.size:
                continue
            pf, cf, df = pm.rows(X, self.local[points[sel]])
            if p is None:
                p, cols = np.zeros((T, K, 3)), np.zeros((K, cf.shape[1]), int)
                dp = [np.zeros((T, K, cf.shape[1])) for _ in range(3)]
            p[:, sel], cols[sel] = pf, cf
            for c in range(3):
                dp[c][:, sel] = np.broadcast_to(df[c], (T, sel.size, cf.shape[1]))
        return p, cols, tuple(dp)

    def roughness(self, linear: bool = True):
        return self.first.roughness(linear)

    def roughness_groups(self, linear: bool = True):
        return self.first.roughness_groups(linear)

    def gauge_constraints(self, full_turns: bool = True):
        return self.first.gauge_constraints(full_turns)

    def gauge(self, n_total=None):
        return self.first.gauge(n_total)

    def layout(self, v, uncertainty: bool = False) -> dict:
        return self.first.layout(v, uncertainty)

    def implausible(self, x) -> list:
        return self.first.implausible(x)

    def station_reference(self):
        p = self.positions()
        return p.mean(axis=0), float(np.linalg.norm(np.ptp(p, axis=0))), "the tool points' diagonal"


# ----------------------------------------------------------------------------------------------- the program
def resolved_linear(linear, campaign, n_unknowns: int = 0):
    """(``linear`` with ``"auto"`` resolved for ``campaign``, why perfect or None): identified when it has distance
    or tracker readings and more readings (components) than ``n_unknowns`` (the model's with the linear axes),
    else perfect. R-test readings alone: nests read the ball's displacement about a few fixed points, the linear
    axes only over the small circles it describes there -- their motions over the travel are unseen (refused as
    physically impossible on one nest), as in an R-test calibration, which takes the linear axes as calibrated.
    Fewer readings than unknowns: the maps' prior already carries the fit; the linear motions would be carried by
    it too (unseen tool points beyond 3 u on 25 commands: 5.8 % with them, under 3 % without, on the truth of
    then)."""
    if linear != LINEAR_AUTO:
        return linear, None
    if not np.any(np.isin(campaign.kind, ("distance", "tracker"))):
        return LINEAR_PERFECT, "an R-test campaign sees them only about its nests"
    if _n_components(campaign) <= n_unknowns:
        return LINEAR_PERFECT, f"{_n_components(campaign)} readings, fewer than the {n_unknowns} unknowns with them"
    return LINEAR_IDENTIFY, None


def _n_components(campaign) -> int:
    """The campaign's scalar readings: 1 per distance, 3 per nest or tracker point."""
    return int(np.sum(np.where(campaign.kind == "distance", 1, 3)))


#: Knot intervals of the default linear-axis splines over the longest linear travel (:func:`linear_knot_spacing`).
LINEAR_INTERVALS = 6


def linear_knot_spacing(machine) -> float:
    """The default knot spacing (mm) of linear axes identified with the rotary ones: :data:`LINEAR_INTERVALS`
    intervals over the longest linear travel (9 coefficients per motion), rounded up to 1 mm. The smoothness
    prior carries what a five-axis campaign reads of them (each position seldom twice, through the rotary axes'
    lever arms); 3 intervals could not hold a truth whose linear axes have error motions, which then went into the
    rotary location errors (measured, docs/five_axis.md, "Linear axes identified with the rotary ones")."""
    k = [machine.axes.index(a) for a in machine.linear]
    travel = max((float(machine.upper[i] - machine.lower[i]) for i in k), default=0.0)
    return float(max(1.0, np.ceil(travel / LINEAR_INTERVALS - 1e-9)))


def error_model(machine, campaign, options: FiveAxisOptions, linear=None, knot_spacing_mm=None) -> FiveAxisErrors:
    """The error model the options ask for on ``machine``: location errors always; the error motions every
    ``pitch_deg`` with ``errormap`` (bidirectional when the campaign has directions); tool offsets; the linear
    axes ``linear``: "identify" (on knots every ``knot_spacing_mm``), known motions, or None (perfect)."""
    if options.model not in MODELS:
        raise InputError(f"--model {options.model}: a five-axis machine takes {' or '.join(MODELS)}")
    tools = options.tool_offsets_mm
    tools = np.zeros((campaign.n_tools, 3)) if tools is None else np.asarray(tools, float).reshape(-1, 3)
    if len(tools) < campaign.n_tools:
        raise InputError(f"--tool-offsets-mm: {len(tools)} offset(s) given, but {campaign.source} uses tool indices "
                         f"0..{campaign.n_tools - 1} (one 'x,y,z' per tool index, separated by ';')")
    return FiveAxisErrors(machine, location=True, motions=options.model == "errormap", pitch_deg=options.pitch_deg,
                          bidirectional=campaign.directions is not None, linear=linear,
                          knot_spacing_mm=knot_spacing_mm or 50.0, tool_offsets_mm=tools,
                          identify_tool_offsets=len(tools) > 1, one_way=one_way(machine, campaign))


def one_way(machine, campaign) -> dict:
    """{rotary letter: its one sign} of the axes every valid row of ``campaign`` approaches from the same side (an
    R-test path turning C one way): no reading tells their branches apart (:class:`FiveAxisErrors` ``one_way``)."""
    d = campaign.directions
    if d is None or not len(d):
        return {}
    d = np.asarray(d, float)
    return {L: float(d[0, k]) for k, L in enumerate(machine.rotary) if np.all(d[:, k] == d[0, k])}


def _stations(campaign, pm, rows, labels):
    """Per station (file labels ``labels``), its start position and dead path: the 3D multilateration of the
    nominal tool points it reads (:func:`~olti_drake.estimation.calibration.station_fit`)."""
    return station_starts(pm.positions()[rows], campaign.reading[rows, 0], campaign.group[rows], labels,
                          campaign.source)


def measurement(campaign, pm):
    """The campaign's readings on position model ``pm`` (point k = row k): one
    :class:`~olti_drake.model.displacements.CombinedMeasurement` of its distance, nest and tracker readings
    (weighed by :data:`MIXED_SIGMAS_MM` when it mixes kinds)."""
    from olti_drake.model.displacements import CombinedMeasurement, NestDisplacementMeasurement, PointMeasurement
    from olti_drake.model.measurements import StationDistanceMeasurement

    parts, kinds = [], []
    rows = np.flatnonzero(campaign.kind == "distance")
    if rows.size:
        labels = np.unique(campaign.group[rows])
        P, L0 = _stations(campaign, pm, rows, labels)
        parts.append(StationDistanceMeasurement(pm, rows, np.searchsorted(labels, campaign.group[rows]),
                                                campaign.reading[rows, 0], P, L0, labels.size, dead_path="L0"))
        kinds.append("distance")
    rows = np.flatnonzero(campaign.kind == "nest")
    if rows.size:
        parts.append(NestDisplacementMeasurement(pm, rows, campaign.group[rows], campaign.reading[rows]))
        kinds.append("nest")
    rows = np.flatnonzero(campaign.kind == "tracker")
    if rows.size:
        parts.append(PointMeasurement(pm, rows, campaign.group[rows], campaign.reading[rows]))
        kinds.append("tracker")
    sigmas = [MIXED_SIGMAS_MM[k] for k in kinds] if len(kinds) > 1 else None
    return CombinedMeasurement(pm, parts, sigmas), kinds


def residual_rows(ident) -> tuple:
    """(campaign row (R,), coordinate (R,)) of every residual row of the identification's measurement, in its
    order (:func:`measurement`: distances one row each, nests and tracker points three, x y z)."""
    rows, coord = [], []
    for k in ident.kinds:
        idx = np.flatnonzero(ident.campaign.kind == k)
        per = 1 if k == "distance" else 3
        rows.append(np.repeat(idx, per))
        coord.append(np.tile(np.arange(per), idx.size))
    return np.concatenate(rows), np.concatenate(coord)


class FiveAxisIdentification(Calibration):
    """A five-axis campaign (:class:`~olti_drake.io.five_axis_io.FiveAxisCampaign`) on ``machine``: the engine's
    :class:`~olti_drake.estimation.calibration.Calibration` of :func:`measurement` over
    :class:`FramedPositionModel`, with the groups the campaign cannot separate held at 0 (:attr:`dropped`: group
    -> reason, said in the notes before solving) and the error motions' gauge.

    Variables: the free location errors (``E_X0C_mm``, … mm, µrad), error-motion nodes (``E_XC_forward_mm[i]``,
    …), ``tool<m>_{x,y,z}_mm``, then the stations' ``P<j>_{x,y,z}_mm`` and ``L0_<j>_mm``, the nests'
    ``nest<n>_{x,y,z}_mm``, the tracker frames' ``frame<g>_…``."""

    budget_kind = "machine"  # (000 Table 2 / 001 Table 4: Calibration.default_budget)

    rank_hint = "add stations, nests or commands spread over the rotary axes' travel"
    #: The residuals beyond the readings' u are a model error every predicted tool point shares
    #: (:meth:`Calibration.lack_of_fit`): a geometric fit of a machine whose axes have error motions.
    predicts_lack_of_fit = True
    untouched_hint = "every station and nest needs readings of commands spread over the travel"

    def __init__(self, campaign, machine, options: FiveAxisOptions = None):
        from olti_drake.io.five_axis_io import in_canonical_order

        campaign = in_canonical_order(campaign)  # (the file's row order decides nothing, to the last bit)
        o = options or FiveAxisOptions()
        auto_perfect, with_linear = None, None  # (why --linear auto took them as perfect; the model counted)
        if o.linear == LINEAR_AUTO:  # (counted on the model with them, at the default knots)
            with_linear = error_model(machine, campaign, o, LINEAR_IDENTIFY,
                                      float(o.knot_spacing_mm or linear_knot_spacing(machine)))
            resolved, auto_perfect = resolved_linear(o.linear, campaign, with_linear.n_params)
            o = dataclasses.replace(o, linear=resolved)
        self._build(campaign, machine, o, with_linear, auto_perfect)
        if with_linear is not None and o.linear == LINEAR_IDENTIFY and not smoothing_on(self._options):
            unseen = self._undetermined_linear()
            if unseen:  # (auto chose them, but without the prior the readings alone do not determine them)
                self._build(campaign, machine, dataclasses.replace(o, linear=LINEAR_PERFECT), None,
                            f"without the smoothness prior (--smoothing off) the campaign does not determine their "
                            f"motions (not identifiable: {unseen})")

    def reading_label(self, k: int) -> dict:
        """Residual row k by its campaign file line, its kind and, for a nest or tracker point, its coordinate."""
        rows = getattr(self, "_rows", None)
        if rows is None:
            rows = self._rows = residual_rows(self)
        i = int(rows[0][k])
        kind = str(self.campaign.kind[i])
        return {"line": int(self.campaign.line[i]), "kind": kind,
                **({} if kind == "distance" else {"coordinate": "xyz"[int(rows[1][k])]})}

    def _undetermined_linear(self) -> str:
        """The linear axes' parameters the identifiability check at the start names (a listing), or '' when it names
        none of them (a refusal of other parameters is the fit's to state)."""
        from olti_drake.estimation.calibration import UnidentifiableError

        linear = set(self.errors.names[self.errors.slices["linear"]])
        try:
            self.check_identifiability()
        except UnidentifiableError as e:
            names = [n for n in e.names if n in linear]
            return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "") if names else ""
        return ""

    def _build(self, campaign, machine, o, with_linear, auto_perfect):
        """The program of ``campaign`` with the options ``o`` (``linear`` resolved; ``with_linear`` the error model
        auto counted with identified linear axes, ``auto_perfect`` why auto took them as perfect)."""
        self._auto_perfect = auto_perfect
        if o.model == "geometric" and o.linear != LINEAR_IDENTIFY:
            o = dataclasses.replace(o, smoothing="off")  # (no maps, no linear motions: nothing to smooth)
        self.campaign, self.machine, self.model_name, self._options = campaign, machine, o.model, o
        self.linear_from, linear, spacing = None, None, None
        if o.linear == LINEAR_IDENTIFY:
            linear = LINEAR_IDENTIFY
            spacing = float(o.knot_spacing_mm or linear_knot_spacing(machine))
        elif o.linear not in (None, LINEAR_PERFECT):
            from olti_drake.io.five_axis_io import load_linear_from

            self.linear_from = load_linear_from(o.linear, machine, campaign.commands, campaign.source)
            linear = self.linear_from.motions
        if o.knot_spacing_mm is not None and linear != LINEAR_IDENTIFY:
            why = f" (--linear auto: {self._auto_perfect})" if self._auto_perfect else ""
            raise InputError(f"--knot-spacing-mm applies to linear axes identified with the rotary ones, not to linear "
                             f"axes {'fixed' if linear is not None else 'perfect'}{why}")
        # (auto's counted model is the one to fit when it chose them: the same options, the same knots)
        self.errors = (with_linear if with_linear is not None and linear == LINEAR_IDENTIFY
                       else error_model(machine, campaign, o, linear, spacing))
        self._settings = dict(location=True, motions=o.model == "errormap", pitch_deg=float(o.pitch_deg),
                              bidirectional=campaign.directions is not None,
                              tool_offsets_mm=self.errors.tools.tolist(),
                              identify_tool_offsets=len(self.errors.tools) > 1)
        if linear == LINEAR_IDENTIFY:
            self._settings.update(linear=LINEAR_IDENTIFY, knot_spacing_mm=spacing)
        self.separability = self._separable()
        self.dropped = {g: self.separability.reasons[g] for g in self.separability.dropped}
        self.position_model = self._framed(self.separability.dropped)
        meas, self.kinds = measurement(campaign, self.position_model)
        gauge = self.position_model.gauge(len(meas.names))
        super().__init__(meas, o, gauge if len(gauge.constraints) else None, campaign.source)
        self.gauge = self._gauge_sentence(gauge)
        self.notes.extend(f"{g}: not separable by this campaign ({why}): held at 0" for g, why in self.dropped.items())
        if self.linear_from is not None:
            self.notes.append(f"linear axes: the 18 error motions and 3 squareness errors of {self.linear_from.path} "
                              f"(sha256 {self.linear_from.sha256[:12]}...) held fixed, not estimated, about the "
                              f"loop's carriage frames; their covariance is propagated into every u "
                              f"(docs/five_axis.md)")
        elif linear == LINEAR_IDENTIFY:
            self.notes.append(f"linear axes: their 18 error motions and 3 squareness errors identified with the rotary "
                              f"axes (B-splines, knots every {spacing:g} mm)")
        else:
            self.notes.append("linear axes: taken as perfect (no error motions, no squareness errors)"
                              + (f" by --linear auto: {self._auto_perfect}; --linear identify asks for them, --linear "
                                 f"RESULT.json takes them from a volumetric calibration" if self._auto_perfect else ""))
        if len(self.kinds) > 1:
            self.notes.append("mixed campaign: each reading kind weighed by its u (mm): " + ", ".join(
                f"{k} {MIXED_SIGMAS_MM[k]:g}" for k in self.kinds))

    def _framed(self, held=()):
        c = self.campaign
        return FramedPositionModel(self.machine, self.errors, c.commands, c.directions, c.tool, c.frame, held)

    def _separable(self):
        """:func:`separable` on the Jacobian of the campaign's own measurement at the start (its stations, nests and
        tracker frames the nuisance), on perfect linear axes: what a campaign separates is structural (known linear
        motions of a few µm break the exact symmetries by their own size, not by what the campaign sees)."""
        pm = self._framed()
        meas, kinds = measurement(self.campaign, pm)
        known, self.errors.linear_motions = self.errors.linear_motions, None
        try:
            _, J = meas.residuals(meas.start_vector())
        finally:
            self.errors.linear_motions = known
        # (the maps' prior without the identified linear axes': a group the campaign cannot see is not made
        # separable by smoothness rows on other motions -- measured, docs/five_axis.md)
        R = meas.roughness(linear=False) if smoothing_on(self._options) else None
        return separable(pm, jacobian=(J, " + ".join(kinds) + " readings, their own unknowns free"), prior=R)

    def _gauge_sentence(self, gauge) -> str:
        frames = sorted(set(self.campaign.frame))
        what = {"distance": "distances see the tool points up to the stations' positions and dead paths",
                "nest": "each nest zero absorbs a translation of the points it sees",
                "tracker": "each tracker frame absorbs a rigid motion of the points it sees"}
        return ("the machine model's own frames (" + ", ".join(frames) + "): " + "; ".join(what[k] for k in self.kinds)
                + "; what the campaign cannot separate is held at 0 (notes)"
                + (f"; {gauge.sentence}" if len(gauge.constraints) else ""))

    def error_model_settings(self) -> dict:
        """The :class:`FiveAxisErrors` keyword arguments of this identification (the result's ``error_model``)."""
        return dict(self._settings)

    def layout(self, v, uncertainty: bool = False) -> dict:
        """Values or uncertainties over :attr:`names` in the ``olti-machine5/1`` keys: the model's
        (``location_errors``, ``error_motions``, ``tool_offset_errors_mm``), then the stations (with their file
        labels and frames), nests and tracker frames."""
        out = self.measurement.layout(np.asarray(v, float), uncertainty)
        c = self.campaign
        rows = c.kind == "distance"
        if rows.any():
            labels = np.unique(c.group[rows])
            out["station_labels"] = labels.tolist()
            out["station_frames"] = [str(c.frame[rows][c.group[rows] == lab][0]) for lab in labels]
        rows = c.kind == "tracker"
        if rows.any():
            labels = np.unique(c.group[rows])
            out["tracker_frame_stands_on"] = [str(c.frame[rows][c.group[rows] == lab][0]) for lab in labels]
        out["held"] = list(self.position_model.held)
        return out

    def solve(self):
        """The fit (:meth:`Calibration.fit`: LM, the covariance and std of every parameter, k = 1)."""
        return self.fit()

    def fit(self, uncertainty: bool = True):
        """:meth:`Calibration.fit`; with linear axes from a volumetric result, the covariance adds what that
        result's own uncertainty (its parameters' covariance, held fixed here) does to the estimate:
        S C_θ Sᵀ, S = dx/dθ = −H⁻¹ Jᵀ J_θ within the gauge (H = JᵀJ + the priors; linear, JCGM 100 §5); with maps,
        their representation on the grid (:meth:`representation`: in the covariance, and as the lack of fit every
        predicted point shares), said in the notes."""
        fit = super().fit(uncertainty)
        if uncertainty and self.linear_from is not None:
            C = self._linear_covariance(fit.x)
            fit.covariance = fit.covariance + C
            fit.std = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))
        if uncertainty and self.errors.maps:
            C, lack = self.representation(fit.x)
            fit.covariance = fit.covariance + C
            fit.std = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))
            # (the residuals' lack of fit and the representation measure one misfit, the maps' between their
            # nodes, where the model has no other: the larger of the two, not their sum)
            fit.lack_of_fit_mm = float(max(fit.lack_of_fit_mm, lack))
            fit.notes.append(f"map representation (JCGM 100 §3.4.1, §4.3: the maps are piecewise linear, the motions "
                             f"between their nodes need not be): per map segment a bubble error of u = 1/8 of the "
                             f"identified nodes' second difference (linear interpolation's error, h² f''/8), its "
                             f"effect on the estimate added to the covariance; its {1e3 * lack:.3g} um at the "
                             f"readings (RMS), or the residuals' lack of fit where larger, added in quadrature to "
                             f"every predicted tool point's u as the lack of fit (docs/five_axis.md)")
        return fit

    def representation(self, x):
        """(C (n, n) over :attr:`names`, e mm): the error motions' representation on their grid as an uncertainty.
        Between two nodes a smooth motion departs from the map's straight line by a bubble a·4t(1−t) (t ∈ [0, 1]
        along the segment; linear interpolation's error h² f''/8 at mid-segment), ``a`` per segment unknown: a
        Type B u (JCGM 100 §4.3; §3.4.1, the model's incompleteness) of 1/8 of the larger second difference of the identified nodes at its ends
        (h² f''). The readings' derivatives in the bubbles, Jt = 4 t (1 − t)·∂r/∂(node), give their effect on the
        estimate, S C_a Sᵀ (:meth:`_propagated`: the location errors it trades with too), and e, their RMS effect
        on a reading (mm of the first reading kind), that a predicted point shares (Fit.lack_of_fit_mm)."""
        _, J = self.residuals(x)
        J = self._pad(J)
        Jt, u2 = self._bubbles(x, J)
        if not u2.size:
            return np.zeros((len(self.names), len(self.names))), 0.0
        return self._propagated(J, Jt, u2), float(np.sqrt(np.mean(Jt.multiply(Jt) @ u2)))

    def _bubbles(self, x, J):
        """(Jt (rows, segments) sparse, u² (segments,)) of :meth:`representation`, over the free maps' segments;
        J the residuals' Jacobian at x (sparse)."""
        from olti_drake.model.five_axis_errors import BRANCHES

        fpm, em = self.position_model, self.errors
        theta = fpm.theta(x)
        remap = np.full(em.n_params, -1)
        remap[fpm.free_cols] = np.arange(fpm.free_cols.size)
        J = sp.csr_matrix(J)
        point = residual_rows(self)[0]
        rows = np.arange(len(point))
        blocks, amps = [], []
        for (L, c), jm in em.maps.items():
            s, n = em.slices[jm.joint], jm.emap.n_nodes
            if n < 3 or remap[s.start] < 0:
                continue  # (a held motion: not estimated; two nodes: no curvature to tell)
            cols, w = np.zeros((fpm.n_points, 2), int), np.zeros((fpm.n_points, 2))
            for f, pm in fpm.parts.items():
                cols[fpm.index[f]], w[fpm.index[f]] = pm._interp[L]
            k = cols[point, 0]  # (each reading's segment: its left node, in its branch's block)
            vals = np.asarray(J[rows, remap[s.start + k]]).ravel() * 4.0 * w[point, 1]
            for b in range(len(BRANCHES[:1 + em.bidirectional])):
                v = theta[s][b * n:(b + 1) * n]
                d = np.abs(np.diff(v, 2))
                d = np.concatenate([d[:1], d, d[-1:]])  # (the end nodes: their neighbour's)
                on = (k >= b * n) & (k < b * n + n - 1)
                blocks.append(sp.csr_matrix((vals[on], (rows[on], k[on] - b * n)), shape=(len(point), n - 1)))
                amps.append(np.maximum(d[:-1], d[1:]) / 8.0)
        if not blocks:
            return sp.csr_matrix((len(point), 0)), np.zeros(0)
        return sp.hstack(blocks, format="csr"), np.concatenate(amps) ** 2

    def _linear_covariance(self, x) -> np.ndarray:
        """S C_θ Sᵀ over :attr:`names` (:meth:`fit`): J_θ by forward differences of the residuals in each
        volumetric parameter (the motions are linear in them: exact to rounding), one step of 10⁻³ (mm, µrad)."""
        lf, em = self.linear_from, self.errors
        r0, J = self.residuals(x)
        J = np.asarray(self._pad(J).todense())
        live = lf.motion_parameters()
        Jt = np.empty((len(r0), live.size))
        try:
            for c, k in enumerate(live):
                theta = lf.params.copy()
                theta[k] += 1e-3
                em.linear_motions = lf.relocated(theta)
                Jt[:, c] = (self.residuals(x)[0] - r0) / 1e-3
        finally:
            em.linear_motions = lf.motions
        return self._propagated(J, Jt, lf.covariance[np.ix_(live, live)])

    def _propagated(self, J, Jt, C_theta) -> np.ndarray:
        """S C_θ Sᵀ over :attr:`names`: what quantities θ held out of the fit (their covariance C_θ, the residuals'
        derivatives Jt in them) do to the estimate, S = dx/dθ = −H⁻¹ Jᵀ Jt within the gauge (H = JᵀJ + the priors
        at the solution, J dense or sparse over all decision variables; linear, JCGM 100 §5)."""
        from scipy.linalg import qr

        def dense(M):
            return M.toarray() if sp.issparse(M) else np.asarray(M)

        H = dense(J.T @ J)
        prior = self._prior_hessian()
        if prior is not None:
            H = H + prior
        A, _ = self._equality_rows()
        N = np.eye(H.shape[0])
        if A.size:  # (the null space of the few gauge rows by a pivoted QR: an n x n SVD took most of the time)
            Q, R, _ = qr(A.T, pivoting=True)
            d = np.abs(np.diag(R))
            N = Q[:, int(np.sum(d > 1e-12 * max(float(d.max(initial=0.0)), 1e-300))):]
        S = -N @ np.linalg.solve(N.T @ H @ N, N.T @ dense(J.T @ Jt))
        C = (S * np.asarray(C_theta, float)) @ S.T if np.ndim(C_theta) == 1 else S @ C_theta @ S.T
        n = len(self.names)
        return ((C + C.T) / 2)[:n, :n]


def identify_five_axis(campaign_path, machine_path, workpiece_frame: str, tool_frame: str,
                       options: FiveAxisOptions = None):
    """Read the machine and the campaign, identify: (identification, fit)."""
    from olti_drake.io.five_axis_io import read_five_axis_campaign
    from olti_drake.model.five_axis import FiveAxisMachine

    machine = FiveAxisMachine.from_file(machine_path, workpiece_frame, tool_frame)
    campaign = read_five_axis_campaign(campaign_path, machine)
    ident = FiveAxisIdentification(campaign, machine, options)
    return ident, ident.solve()
