"""Identification of an N-joint serial robot (any model Drake loads) from a distance or point campaign.

000 §3 in 3D: the position model of :mod:`olti_drake.model.serial` (location errors of every joint
frame reduced to the base set, the tool-point offset, per-joint ``dh`` offsets or bidirectional
``errormap`` maps, 000 Eq. (6)–(9)) under a :class:`~olti_drake.model.serial.DistanceMeasurement`
(stations P_j and dead paths d0_j, 000 Eq. (10) in 3D) or a
:class:`~olti_drake.model.serial.PointMeasurement` (a tracker in an unknown rigid frame), solved by the
shared least-squares program (:class:`~olti_drake.estimation.calibration.Calibration`: LM steps as Drake
programs or an NLP solver, robust loss, outliers by file line, linear covariance, refusal of a fit
that did not converge) with the gauge of :func:`~olti_drake.model.serial.find_gauge` as named linear
constraints.

Start: the nominal chain with the given tool offset, zero maps; stations by the linearized
multilateration of the nominal tool points refined by Gauss-Newton (``station_fit``); the tracker frame
by the least-squares rigid fit (Kabsch) of the nominal tool points to the tracker's.

Identifiability is checked before solving: parameters the readings cannot determine are refused by
name, or with ``regularize`` given a stated weak prior: each named parameter ~ N(start,
:data:`PRIOR_SIGMA`) (1 mm for lengths, 1 deg for angles) weighed against the campaign's own reading
uncertainty u_r (the budget's, else the robust sigma of the fit linearized at the start; at least
:data:`PRIOR_READING_MM`), i.e. the quadratic cost ½ (u_r/σ)² (x − x0)² next to the data cost ½ Σ r².
Judged also by u, not only by rank (issue 23): a location error, joint offset or tool coordinate whose u at
the start would exceed :data:`U_BOUND` (10 mm, 5 deg) is named with its u -- with ``regularize`` it gets
the weak prior N(start, U_BOUND); without, the fit is tried anyway and refused by name when its u at the
solution still exceeds the bound. Units: mm and degrees.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence

import numpy as np

from olti_drake.errors import InputError
from olti_drake.estimation.calibration import Calibration, station_fit
from olti_drake.estimation.calibration import FitRefused, SolverOptions, UnidentifiableError, suspect_readings_line
from olti_drake.estimation.resolution import Finer, inflate, resolution_check as compare_representations
from olti_drake.estimation.resolution import summary_line
from olti_drake.model.chain import plane_frame, robot_plane
from olti_drake.model.frames import rigid_fit, xyz_angles
from olti_drake.model.serial import DistanceMeasurement, PointMeasurement, build_position_model, find_gauge

#: Standard deviation of the weak prior ``regularize`` puts on a parameter the data cannot identify, by unit.
PRIOR_SIGMA = {"_mm": 1.0, "_deg": 1.0}
#: The least reading standard uncertainty the prior is weighed against (mm): the prior counts as much as a
#: reading of the campaign's own reading uncertainty (:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.
#: reading_sigma`: the budget's, else the robust sigma of the fit linearized at the start) would that measured the
#: parameter directly with uncertainty PRIOR_SIGMA -- never less than this (exact readings of a simulation).
PRIOR_READING_MM = 1e-3
#: The largest plausible standard uncertainty of a location error, joint offset or tool coordinate (1/5 and 1/2 of
#: :attr:`~olti_drake.model.serial.SerialPositionModel.LOCATION_BOUND_MM` / ``LOCATION_BOUND_DEG``, so that a
#: result within ~2 u of its start stays inside those bounds): one whose u at the start would exceed it is not
#: identifiable (named with its u), or with ``regularize`` gets a weak prior of this sigma.
U_BOUND = {"_mm": 10.0, "_deg": 5.0}


#: The default map grid with the smoothness prior (deg): the prior holds thin nodes between read ones, so the
#: grid may follow deviations of shorter period (random-pose six-axis campaigns, issue 23: unseen-reading RMS
#: 4-11 um on 7.5 deg against 5-21 um on 15 deg); without it, the grid whose nodes readings can determine.
SMOOTH_GRID_STEP_DEG = 7.5
PLAIN_GRID_STEP_DEG = 15.0


def grid_step(options) -> float:
    """The map grid step of ``options`` (deg): its own, or the default for its smoothing."""
    if options.grid_step_deg is not None:
        return float(options.grid_step_deg)
    return PLAIN_GRID_STEP_DEG if options.smoothing == "off" else SMOOTH_GRID_STEP_DEG


def check_serial_map_size(data, options) -> None:
    """Refuse (:func:`olti_drake.limits.check_allocation`), before the model is built, a ``grid_step_deg`` whose
    maps would need more than the limit: the identification's peak is the dense normal matrix (n, n) of the n
    parameters (every map node, twice when bidirectional, plus the geometry), and the Jacobian (rows, n). An upper
    bound: it counts a map on every joint (the model leaves out a joint no reading depends on, e.g. the UR5's
    wrist 3 for a tool point on its axis: n is then ~1.4x smaller)."""
    from olti_drake.limits import check_allocation

    if options.model != "errormap" or options.grids is not None:
        return
    step = grid_step(options)
    if not (math.isfinite(step) and step > 0):
        return  # refused by name where the grid is made
    th = np.asarray(data.commands, float)
    if th.ndim != 2 or not th.size or not np.all(np.isfinite(th)):
        return
    lo, hi = th.min(axis=0), th.max(axis=0)
    nodes = np.ceil(hi / step - 1e-9) - np.floor(lo / step + 1e-9) + 1
    n = float(np.sum(nodes)) * (1 if data.dirs is None else 2) + 6 * th.shape[1] + 3
    rows = 3.0 * len(th)
    value = f"{step:g} deg"
    check_allocation("--grid-step-deg", value, [n, n], what="parameters squared (the dense normal matrix)",
                     hint="use a coarser --grid-step-deg")
    check_allocation("--grid-step-deg", value, [rows, n], what="Jacobian entries (readings x map parameters)",
                     hint="use a coarser --grid-step-deg")


@dataclass
class SerialIdentificationOptions(SolverOptions):
    """What to identify (mm, deg), plus the solver options of :class:`SolverOptions`.

    ``model``: 'dh' (geometric) or 'errormap' (+ per-joint maps every ``grid_step_deg`` over each
    joint's commanded range); ``tool_offset_mm``: the nominal tool point in the tool frame (start).
    """

    model: str = "errormap"
    tool_offset_mm: Sequence[float] = (0.0, 0.0, 0.0)
    #: Map nodes every this many degrees; None: :data:`SMOOTH_GRID_STEP_DEG` with the smoothness prior,
    #: :data:`PLAIN_GRID_STEP_DEG` without.
    grid_step_deg: Optional[float] = None
    #: Joint compliance under gravity (``--compliance``, :func:`~olti_drake.model.serial.build_position_model`).
    compliance: bool = False
    #: Dead-path drift of every station in time (``--drift``; distance campaigns with ``time_s``).
    drift: bool = False
    #: Map nodes per joint name (deg), instead of every ``grid_step_deg`` (e.g. the SCARA path's grids).
    grids: Optional[Dict[str, Sequence[float]]] = None
    #: The maps' roughness prior (issue 23): 'auto' (weight by restricted maximum likelihood), 'off', or a weight (SolverOptions.smoothing).
    smoothing: object = "auto"
    #: 'auto' (as ``olti identify --robot``): l2 unless its residuals show outliers, then Huber (SolverOptions.loss).
    loss: str = "auto"
    #: Run the under-resolution check (:func:`resolution_check`) on an error-map fit whose grid the user chose or
    #: that has no smoothness prior (with the prior on the default grid the prior, not the grid, sets what the maps
    #: hold).
    check_resolution: bool = True


@dataclass
class SerialIdentification:
    """The identified problem: ``measurement`` (its model), the fit, the gauge sentence, the notes."""

    measurement: object
    fit: object
    gauge: str
    notes: list = field(default_factory=list)
    #: A planar robot's stations off its plane (labels), and those of them placed above it (:func:`_choose_sides`).
    off_plane: tuple = ()
    above: tuple = ()

    @property
    def model(self):
        return self.measurement.model

    @property
    def residual_rms_mm(self) -> float:
        r = self.fit.residuals
        return float(np.sqrt(np.mean(r * r))) if len(r) else 0.0


class SerialCalibration(Calibration):
    """:class:`Calibration` whose readings are named by file line (outliers) and whose hints speak of
    stations, directions and ``--regularize``."""

    rank_hint = "add stations, approach directions or poses, or run with --regularize"
    untouched_hint = "add readings that move those joints, or run with --regularize"
    vague_hint = ("add stations or poses that move those joints further, or run with --regularize (a weak prior "
                  "of that sigma, stated)")
    #: olti predict adds the fit's lack of fit to the u of its tool points and readings.
    predicts_lack_of_fit = True

    def plausible_u(self):
        """:data:`U_BOUND` for the position model's location errors, joint offsets and tool point (not map nodes,
        not the stations, dead paths or tracker frame: inf)."""
        model = self.measurement.model
        own = set(model.names)
        return np.array([_u_bound(n) if n in own and "[" not in n else np.inf for n in self.names])

    def __init__(self, measurement, options, gauge, source, lines):
        super().__init__(measurement, options, gauge, source)
        self._lines = np.asarray(lines)
        self._per_reading = 3 if measurement.kind == "point" else 1

    def reading_label(self, k: int) -> dict:
        i = int(k) // self._per_reading
        out = {"line": int(self._lines[i])}
        if self._per_reading == 3:
            out["coordinate"] = "xyz"[int(k) % 3]
        return out


#: A planar robot's station counts as off the robot's plane when fitting its height lowers the RMS of its
#: start fit to the nominal tool points at least this many times: distances then see the out-of-plane
#: parameters at first order, and the campaign is identified in 3D (not the planar reduction).
OFF_PLANE_RMS_RATIO = 2.0
#: ... and its fitted height is at least this (mm): exact readings leave both fits at rounding level.
OFF_PLANE_MIN_MM = 1.0


def start_stations(model, campaign, planar=None, heights=None) -> tuple:
    """Stations (Nt, 3) and dead paths (Nt,) mm fitted to the nominal tool points (station_fit).

    ``planar``: a planar robot's plane (a root axis or a unit normal, :func:`~olti_drake.model.chain.robot_plane`):
    each station is fitted in the plane (2D, 000 Eq. (5)) and placed at the tool points' level along its
    normal (held there). ``heights``: (normal, plane level, {station: (P (3,), d0)}) of
    :func:`off_plane_stations`, used as they are."""
    if heights is not None:
        fits = heights[2]
        return (np.array([fits[j][0] for j in np.unique(campaign.station)]),
                np.array([fits[j][1] for j in np.unique(campaign.station)]))
    p = model.positions(campaign.commands, campaign.dirs)
    n, E = plane_frame(planar)[:2] if planar is not None else (np.zeros(3), np.eye(3))
    P, d0 = [], []
    for j in np.unique(campaign.station):
        sel = campaign.station == j
        Pf, d0j = _station_start(campaign, j, p[sel] @ E, campaign.displacement_mm[sel])
        P.append(E @ Pf + np.mean(p[sel] @ n) * n)  # (a root axis: the coordinates as they are, bit for bit)
        d0.append(d0j)
    return np.array(P), np.array(d0)


def _station_start(campaign, j, points, readings):
    try:
        return station_fit(points, readings)
    except ValueError as e:
        raise InputError(f"{campaign.source}: station {j}: the nominal tool points of its readings: {e}") from None


def off_plane_stations(chain, campaign, tool_offset_mm, normal, above=()):
    """A planar robot (tool points in the plane of unit ``normal``, (3,)) measured from stations off that
    plane (a tracer on the floor below a SCARA's working plane): (normal, the plane's level along it mm,
    {station: (P (3,) mm, d0 mm)}, the labels of the stations off the plane) with each station's height
    fitted beside its in-plane position and dead path (d + d0 = √(ρ² + h²)), when any station is off the
    plane (:data:`OFF_PLANE_RMS_RATIO`); None when all lie in it (the planar problem).

    Distances cannot tell a station above the plane from its mirror image below: off-plane stations are
    placed below (against the normal), those labelled in ``above`` above; the mirror of all of them together
    is the same fit (:func:`_choose_sides` picks the sides against each other)."""
    # In-plane axes: the root axes other than the normal's when it is one (the same numbers as the planar
    # problem's in-plane coordinates), else an orthonormal pair.
    n, E, _ = plane_frame(normal)
    p = chain.positions(campaign.commands, chain.nominal_parameters(tool_offset_mm))
    level = float(np.mean(p @ n))
    fits, off = {}, []
    for j in np.unique(campaign.station):
        sel = campaign.station == j
        q, d = p[sel] @ E, campaign.displacement_mm[sel]
        P2, d02 = _station_start(campaign, j, q, d)
        rms_flat = _rms_height(q, d, P2, 0.0, d02)
        P2h, h, d0h = _height_fit(q, d, P2)
        rms_high = _rms_height(q, d, P2h, h, d0h)
        if rms_flat > OFF_PLANE_RMS_RATIO * rms_high and h > OFF_PLANE_MIN_MM:
            off.append(int(j))
            fits[j] = (E @ P2h + (level + (h if j in above else -h)) * n, d0h)
        else:
            fits[j] = (E @ P2 + level * n, d02)
    return (n, level, fits, tuple(off)) if off else None


def _rms_height(q, d, P2, h, d0) -> float:
    return float(np.sqrt(np.mean((np.sqrt(np.sum((q - P2) ** 2, axis=1) + h * h) - d0 - d) ** 2)))


def _height_fit(q, d, P2):
    """(P (2,), h ≥ 0, d0) of d = √(|q − P|² + h²) − d0 for in-plane points q (K, 2), mm: Gauss-Newton from
    the in-plane fit with heights of ¼ to 2 median in-plane distances (h = 0 is a stationary point: no
    step leaves it), the best kept."""
    rho = np.median(np.linalg.norm(q - P2, axis=1))
    best = None
    for h0 in (0.25, 0.5, 1.0, 2.0):
        z = np.concatenate([P2, [h0 * rho], [0.0]])
        z[3] = np.mean(np.sqrt(np.sum((q - z[:2]) ** 2, axis=1) + z[2] ** 2) - d)
        for _ in range(50):
            diff = q - z[:2]
            dist = np.sqrt(np.sum(diff ** 2, axis=1) + z[2] ** 2)
            J = np.column_stack([-diff / dist[:, None], z[2] / dist, -np.ones(len(d))])
            step = np.linalg.lstsq(J, -(dist - z[3] - d), rcond=None)[0]
            z = z + step
            if np.max(np.abs(step)) < 1e-9:
                break
        cost = _rms_height(q, d, z[:2], z[2], z[3])
        if np.isfinite(cost) and (best is None or cost < best[0]):
            best = (cost, z.copy())
    if best is None:  # (no start converged: the station stays in the plane)
        return P2, 0.0, float(np.mean(np.linalg.norm(q - P2, axis=1) - d))
    z = best[1]
    return z[:2], abs(float(z[2])), float(z[3])


def start_frame(model, campaign) -> np.ndarray:
    """Tracker frame (t mm, Rx·Ry·Rz angles deg) of the rigid fit m ≈ R p + t of the nominal tool
    points p to the measured ones m (Kabsch, :func:`~olti_drake.model.frames.rigid_fit`)."""
    try:
        rot, t = rigid_fit(model.positions(campaign.commands, campaign.dirs), campaign.points_mm)
    except InputError as e:
        raise InputError(f"{campaign.source}: the tracker frame's start: {e}") from None
    return np.concatenate([t, xyz_angles(rot)])


def build_problem(chain, campaign, options: SerialIdentificationOptions, above=()):
    """The measurement problem of a campaign at its start (nominal robot, fitted stations / frame).

    A distance campaign of a planar robot (:func:`~olti_drake.model.chain.planar_axis`: the SCARA of
    000 as ``models/scara.sdf`` to its ``beam`` frame; or a plane normal to no root axis,
    :func:`~olti_drake.model.chain.planar_normal`: a model file that tilts the base) is the planar
    problem: the out-of-plane parameters dropped by name (``base_parameter_set(planar=...)``), the
    stations 2D in the plane at the tool point's level -- unless its stations stand off that plane
    (:func:`off_plane_stations`): then the 3D problem, the stations started at their fitted heights
    (``above``: those placed above the plane).
    Returns (measurement, notes, labels of the stations off the plane)."""
    nominal = chain.nominal_parameters(options.tool_offset_mm)
    plane = robot_plane(chain, nominal) if campaign.kind == "distance" else None  # along a root axis or not
    heights = (off_plane_stations(chain, campaign, options.tool_offset_mm, plane_frame(plane)[0], above)
               if plane is not None else None)
    planar = None if heights is not None else plane  # stations off the plane see the robot in 3D: not planar
    model = build_position_model(chain, campaign.commands, campaign.dirs, kind=options.model,
                                 grid_step_deg=grid_step(options), grids=options.grids,
                                 tool_offset_mm=options.tool_offset_mm, compliance=options.compliance,
                                 planar=planar)
    if options.drift and (campaign.kind != "distance" or campaign.time_s is None):
        raise InputError(f"{campaign.source}: --drift needs a distance campaign with a 'time_s' column (the time of "
                         f"every reading, s)")
    if campaign.kind == "distance":
        P, d0 = start_stations(model, campaign, planar, heights)
        notes = [] if heights is None else [
            f"a planar robot measured from stations off its plane (their heights above it fitted at the start: "
            f"{', '.join(f'{z - heights[1]:.0f}' for z in P @ heights[0])} mm): identified in 3D, the "
            f"out-of-plane parameters seen through the beams' slope; the mirror image of all the stations "
            f"together fits the same (the first is placed below)"]
        if np.ndim(planar) == 1:
            n, _, h = plane_frame(planar)
            free = "".join(c for k, c in enumerate("xyz") if k != h)
            notes.append(f"a planar robot whose plane is tilted in its model file (normal "
                         f"({', '.join(f'{c:.4g}' for c in n)})), measured from stations in that plane: the planar "
                         f"reduction on it; each station's {'xyz'[h]} follows from its {free} (the station held in "
                         f"the plane: u of {'xyz'[h]} stated 0)")
        return DistanceMeasurement(model, campaign.commands, campaign.dirs, campaign.station,
                                   campaign.displacement_mm, P, d0,
                                   time_h=campaign.time_s / 3600.0 if options.drift else None,
                                   plane=planar), notes, (() if heights is None else heights[3])
    return PointMeasurement(model, campaign.commands, campaign.dirs, campaign.points_mm,
                            start_frame(model, campaign)), [], ()


def _by_unit(name: str, table: dict) -> float:
    for suffix, value in table.items():
        if name.endswith(suffix) or suffix + "[" in name:
            return value
    return 1.0


def _u_bound(name: str) -> float:
    return _by_unit(name, U_BOUND) if name.endswith(("_mm", "_deg")) else np.inf


def prior_sigma(name: str) -> float:
    """The ``regularize`` prior's σ of a parameter the readings cannot identify (:data:`PRIOR_SIGMA`, by unit)."""
    return _by_unit(name, PRIOR_SIGMA)


def prior_weight(name: str, reading_mm: float = PRIOR_READING_MM, sigma: Optional[float] = None) -> float:
    """Weight (u_r/σ)² of the ``regularize`` prior on a parameter: σ its :func:`prior_sigma` (or ``sigma``), u_r
    the reading uncertainty it is weighed against (mm, at least :data:`PRIOR_READING_MM`)."""
    sigma = prior_sigma(name) if sigma is None else float(sigma)
    return (max(float(reading_mm), PRIOR_READING_MM) / sigma) ** 2


def _regularize(cal: SerialCalibration, names, u_at_start=None) -> str:
    """The weak stated prior N(start, σ) on ``names``, weighed against the campaign's reading uncertainty
    (:meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.reading_sigma`): σ :data:`PRIOR_SIGMA` for what
    the rank cannot determine; for what it determines too vaguely (``u_at_start``: {name: u}) σ
    :data:`U_BOUND`. The note says which, with σ and the reading u."""
    u_at_start = u_at_start or {}
    idx = [cal.names.index(n) for n in names]
    reading, what = cal.reading_sigma()
    u_r = max(reading, PRIOR_READING_MM)
    sigma = np.array([_u_bound(n) if n in u_at_start else prior_sigma(n) for n in names])
    w = np.array([prior_weight(n, u_r, s) for n, s in zip(names, sigma)])
    binding = cal.prog.AddQuadraticCost(np.diag(w), -w * cal.x0[idx], cal.variables[idx], is_convex=True)
    binding.evaluator().set_description("prior (olti identify --regularize)")
    listing = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    weighed = (f"weighed against readings of {1e3 * u_r:.3g} um ({what}"
               + (", at least 1 um" if u_r > reading else "") + ")")
    if u_at_start:
        shown = ", ".join(f"{n} {u_at_start[n]:.3g}" for n in names[:8])
        return (f"regularized: the readings determine {listing} only vaguely (u at the start {shown}, beyond "
                f"{U_BOUND['_mm']:g} mm or {U_BOUND['_deg']:g} deg); each has a weak prior N(start, sigma) with "
                f"sigma {U_BOUND['_mm']:g} mm or {U_BOUND['_deg']:g} deg, {weighed} "
                f"(estimation.serial_identification.U_BOUND)")
    return (f"regularized: the readings cannot identify {listing}; each has a weak prior N(start, sigma) "
            f"with sigma {PRIOR_SIGMA['_mm']:g} mm or {PRIOR_SIGMA['_deg']:g} deg, {weighed} "
            f"(estimation.serial_identification.PRIOR_SIGMA)")


#: A fitted tool point this far (mm) from the start that was given (or the tool frame's origin) rebuilds the
#: model around it: the start decides which parameters the readings can see (a tool point on the last axis
#: hides that joint's map), so a campaign run without ``--tool-offset-mm`` loses nothing.
TOOL_RESTART_MM = 1.0


def _unseen_at_start(model) -> list:
    return [name for name, why in model.dropped if why.startswith("no reading depends")]


def identify_serial(chain, campaign, options: SerialIdentificationOptions) -> SerialIdentification:
    """Identify the model ``options.model`` of ``chain`` from ``campaign`` (io.serial_io.SerialCampaign).

    Raises (one line) before solving when the campaign cannot identify a parameter (named), unless
    ``options.regularize``; refuses a fit that did not converge (calibration.FitRefused). The program is
    re-built around the first fit where that fit shows a better start (:func:`_refined`)."""
    return serial_problem(chain, campaign, options)[1](pristine=True)


def _refined(chain, campaign, options, ident: SerialIdentification) -> SerialIdentification:
    """The identification again around what the first fit showed: a planar robot's stations off its plane on
    their sides (:func:`_choose_sides`); a model rebuilt around the fitted tool point when parameters were left
    out because the start's tool point lies on a joint axis and the fitted one does not (:data:`TOOL_RESTART_MM`),
    the notes saying so."""
    ident = _choose_sides(chain, campaign, options, ident)
    unseen = _unseen_at_start(ident.model)
    if not unseen:
        return ident
    n = ident.model.n_params
    tool = ident.model.chain_parameters(ident.fit.x[:n])[-3:]
    moved = float(np.linalg.norm(tool - np.asarray(options.tool_offset_mm, float)))
    if moved < TOOL_RESTART_MM:
        return ident
    again = dataclasses.replace(options, tool_offset_mm=tuple(tool))
    second = _identify_once(chain, campaign, again, ident.above)
    if len(_unseen_at_start(second.model)) >= len(unseen):
        return ident
    second.notes.insert(0, f"the tool point was fitted at ({tool[0]:.3f}, {tool[1]:.3f}, {tool[2]:.3f}) mm in the "
                           f"tool frame, {moved:.1f} mm from the start: the model was rebuilt around it and "
                           f"identified again, so {', '.join(unseen)} (unseen from the start, the tool point on the "
                           f"axis) are identified")
    return second


def _choose_sides(chain, campaign, options, ident: SerialIdentification) -> SerialIdentification:
    """The sides of a planar robot's stations off its plane, against each other. Distances cannot tell the
    mirror image of all stations together, but one station's side against another's they see through the
    robot's out-of-plane errors (a tilt brings the tool point nearer to a station above and farther from one
    below). Local search: every off-plane station but the first is tried on the other side and left there
    when the fit's cost drops by more than 1e-3 of itself, in passes until none moves (an identification per
    try)."""
    best, above = ident, frozenset()
    for _ in range(len(ident.off_plane)):
        moved = False
        for j in ident.off_plane[1:]:
            sides = above ^ {j}
            try:
                trial = _identify_once(chain, campaign, options, tuple(sorted(sides)))
            except InputError:  # (refused on that side: not a better one)
                continue
            if np.sum(trial.fit.residuals ** 2) < (1 - 1e-3) * np.sum(best.fit.residuals ** 2):
                best, above, moved = trial, sides, True
        if not moved:
            break
    if len(ident.off_plane) > 1:
        best.notes.append(f"stations off the plane, sides chosen by the fit's cost (each but station "
                          f"{ident.off_plane[0]} tried on the other side): "
                          + ", ".join(f"{j} {'above' if j in above else 'below'}" for j in ident.off_plane))
    return best


def _identify_once(chain, campaign, options: SerialIdentificationOptions, above=()) -> SerialIdentification:
    return serial_problem(chain, campaign, options, above)[1]()


def serial_problem(chain, campaign, options: SerialIdentificationOptions, above=()):
    """The calibration program of an N-joint campaign at its start, before the solve: (SerialCalibration,
    finish) -- ``finish()`` fits it (naming what the readings cannot see, or regularizing it with
    ``options.regularize``) and returns the :class:`SerialIdentification`. The program's notes say what was
    dropped and why. ``above``: a planar robot's stations placed above its plane (:func:`_choose_sides`)."""
    meas, notes, off_plane = build_problem(chain, campaign, options, above)
    try:
        gauge = find_gauge(meas)
    except ValueError as e:
        raise InputError(f"{campaign.source}: {e}") from None
    solver = SolverOptions(loss=options.loss, huber_k=options.huber_k, outlier_threshold=options.outlier_threshold,
                           regularize=False, solver=options.solver, max_iterations=options.max_iterations,
                           budget=options.budget, smoothing=options.smoothing)
    cal = SerialCalibration(meas, solver, gauge, campaign.source, campaign.line)
    notes += [f"dropped from the model: {len(meas.model.dropped)} parameter(s) the readings cannot separate "
              f"(listed under 'dropped' with the reason)"] if meas.model.dropped else []
    if campaign.dirs is None and options.model == "errormap":
        notes.append("one-directional campaign (no dir columns): single-branch maps, no backlash identified")

    def finish(pristine: bool = False) -> SerialIdentification:
        """The fit; ``pristine`` (nothing added to the program, no solution given): then :func:`_refined`."""
        # fit() checks identifiability first (one factorization: at thousands of unknowns the check's own is
        # reused by the solver and the covariance); what it cannot see is named, or regularized and fitted again.
        # A parameter whose u at the start is beyond what is plausible (SerialCalibration.plausible_u) gets the
        # weak prior with options.regularize; without it the fit is tried anyway -- the start's u can mislead (a
        # tool point started on the last axis hides the wrist) -- and judged by the u at its solution.
        said, start_error = list(notes), None
        try:
            for _ in range(len(cal.names)):
                try:
                    fit = cal.fit()
                    break
                except UnidentifiableError as e:
                    refused = isinstance(e, FitRefused)  # (VagueSolution: u beyond plausible at the solution)
                    if getattr(e, "u_at_start", None) and not refused and not options.regularize \
                            and cal.vague_at_start:
                        start_error, cal.vague_at_start = e, False
                        continue
                    if not options.regularize or not e.names:
                        raise InputError(str(e) if refused else f"{campaign.source}: {e}") from None
                    said.append(_regularize(cal, [n for n in e.names if n in cal.names],
                                            getattr(e, "u_at_start", None)))
            else:  # (each round adds priors to what was named: all are determined long before this)
                raise InputError(f"{campaign.source}: regularization did not make every parameter identifiable")
        except FitRefused as e:
            if start_error is None:
                raise
            raise FitRefused(f"{campaign.source}: refused, nothing written -- {start_error}; solved anyway: "
                             f"{str(e).split(' -- ', 1)[-1]}") from None
        ident = SerialIdentification(meas, fit, cal.gauge, said, off_plane, tuple(above))
        if not pristine:
            return ident
        ident = _refined(chain, campaign, options, ident)
        inflate(ident.fit, resolution_check(chain, campaign, options, ident))
        return ident
    return cal, finish


def resolution_check(chain, campaign, options, ident: SerialIdentification) -> Optional[dict]:
    """The engine's under-resolution check (:func:`olti_drake.estimation.resolution.resolution_check`) of an
    error-map fit: the campaign identified again with every map's grid halved (a node between each two; 000 Eq. 9
    interpolates between them) and the tool points of the two at the campaign's commands compared against their
    stated u. None when there is nothing to check (a geometric model, no map, the check off, or the smoothness
    prior on the default grid -- see :attr:`SerialIdentificationOptions.check_resolution`)."""
    from olti_drake.model.serial import tool_point_uncertainty

    if options.model != "errormap" or not options.check_resolution or not ident.model.maps or (
            options.smoothing != "off" and options.grid_step_deg is None and options.grids is None):
        return None
    step = grid_step(options)
    finer_options = dataclasses.replace(options, check_resolution=False, grid_step_deg=step / 2, grids=None if
                                        options.grids is None else {j: _halved(g) for j, g in options.grids.items()})
    this, finer = ((f"a {step:g} deg grid", f"a {step / 2:g} deg grid") if options.grids is None else
                   ("the given grids", "the given grids with a node between each two"))
    check = Finer(this=this, finer=finer, rerun=f"--grid-step-deg {step / 2:g}" if options.grids is None else
                  "a node between each two of the given grids",
                  extra={} if options.grids is not None else {"grid_step_deg": step, "finer_grid_step_deg": step / 2})
    meas = ident.measurement

    def points(result, m):
        model = m.model
        idx = [list(result.fit.names).index(n) for n in model.names]
        C = result.fit.covariance[np.ix_(idx, idx)]
        return tool_point_uncertainty(model.with_vector(result.fit.x[idx]), meas.commands, meas.dirs, cov=C)

    def finer_points():
        check_serial_map_size(campaign, finer_options)
        other = _identify_once(chain, campaign, finer_options, ident.above)
        return points(other, other.measurement)
    check.points = finer_points
    return compare_representations(*points(ident, meas), check)


def _halved(grid) -> list:
    """A map grid (deg) with a node half-way between each two."""
    g = np.asarray(grid, float)
    return np.union1d(g, (g[:-1] + g[1:]) / 2).tolist()


def summary(ident: SerialIdentification) -> str:
    """Short text: model, readings, parameters, residual RMS, iterations, conditioning, gauge, maps."""
    m, fit = ident.model, ident.fit
    u = dict(zip(fit.names, fit.std))
    lines = [f"model {m.kind} of {m.chain.path} to '{m.chain.tool_frame}' ({m.chain.n_joints} joints): "
             f"{len(ident.measurement.commands)} readings ({ident.measurement.kind}), {len(fit.names)} parameters "
             f"({len(m.geometric_names)} location errors kept, {len(m.dropped)} dropped), solver {fit.solver}"]
    tool = m.chain_parameters(fit.x[:m.n_params])[-3:]
    ut = [u.get(n, 0.0) for n in ("tool_x_mm", "tool_y_mm", "tool_z_mm")]
    lines.append("  tool offset (" + ", ".join(f"{v:.4f}" for v in tool) + ") +- ("
                 + ", ".join(f"{v:.4f}" for v in ut) + ") mm (k = 1)")
    for s, mp in zip(m.map_starts, m.maps):
        vals = fit.x[s:s + mp.n_values]
        std = fit.std[s:s + mp.n_values]
        lines.append(f"  {mp.joint} map: {mp.emap.n_nodes} nodes {mp.emap.grid_deg[0]:g}..{mp.emap.grid_deg[-1]:g} "
                     f"deg{'' if mp.bidirectional else ' (one branch)'}, deviation {1e3 * vals.min():.2f}.."
                     f"{1e3 * vals.max():.2f} mdeg, u up to {1e3 * std.max():.3f} mdeg")
    lines.append(f"  residual RMS {1e3 * ident.residual_rms_mm:.3f} um, {fit.iterations} iterations, condition "
                 f"number {fit.condition_number:.3g} (scaled, within the gauge)")
    lines.append(f"  gauge: {ident.gauge}")
    for note in list(fit.notes) + list(ident.notes):
        lines.append(f"  note: {note}")
    check = summary_line(fit.resolution)
    lines += [check] if check else []
    for w in fit.warnings:
        lines.append(f"  warning: {w}")
    lines += [t for t in [suspect_readings_line(fit.outliers)] if t]
    return "\n".join(lines)
