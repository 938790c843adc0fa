"""Uncertainty of a robot identified from a model file (issue 13, item 7): every parameter, and the predicted
tool point over the workspace.

* :func:`calibration_at_result` -- the identification program of a result on its own campaign, at the
  identified values (the model, stations and dead paths or the tracker frame, the drift), with the gauge of
  :func:`~olti_drake.model.serial.find_gauge`: the input of the linear propagation (JCGM 100) and of the Monte
  Carlo (JCGM 101) of :mod:`olti_drake.estimation.uncertainty`.
* :func:`tool_point_uncertainty` -- u of the predicted tool point, u_p = sqrt(diag(J_p C J_pᵀ)) per coordinate
  (mm, k = 1), for commands and directions, from the covariance C of the model's parameters (linear) or from
  Monte Carlo samples of them (the sample spread of the predicted points).
* :func:`workspace_uncertainty` -- the same over seeded workspace poses in the model's commanded ranges: the 3D
  map the report and ``olti uncertainty --map`` show as slices.

Units: mm and degrees; uncertainties standard (k = 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.propagation import predicted_std, with_lack_of_fit
from olti_drake.model.serial import tool_point_uncertainty


def calibration_at_result(result, campaign):
    """(program, x): the result's identification program on ``campaign`` at the identified values.

    ``result``: :class:`~olti_drake.io.serial_io.SerialResult`; ``campaign``:
    :class:`~olti_drake.io.serial_io.SerialCampaign` (the one the result came from)."""
    from olti_drake.estimation.calibration import SolverOptions
    from olti_drake.estimation.serial_identification import SerialCalibration
    from olti_drake.model.chain import robot_plane
    from olti_drake.model.serial import DistanceMeasurement, PointMeasurement, find_gauge

    model = result.model
    if campaign.kind == "distance":
        if result.stations_mm is None:
            raise InputError(f"{campaign.source}: a distance campaign, but the result was identified from tracker "
                             f"points")
        labels = np.unique(campaign.station)
        if not np.array_equal(labels, result.station_labels):
            raise InputError(f"{campaign.source}: stations {list(labels)}, the result has "
                             f"{list(result.station_labels)}: not the campaign of this result")
        data = result.data
        drift = "drift_mm_per_h" in data
        if drift and campaign.time_s is None:
            raise InputError(f"{campaign.source}: the result has a dead-path drift (--drift): the campaign needs "
                             f"its 'time_s' column")
        meas = DistanceMeasurement(model, campaign.commands, campaign.dirs, campaign.station,
                                   campaign.displacement_mm, result.stations_mm, result.dead_paths_mm,
                                   time_h=campaign.time_s / 3600.0 if drift else None,
                                   drift_mm_per_h=data.get("drift_mm_per_h"),
                                   drift_reference_h=data.get("drift_reference_h"),
                                   plane=robot_plane(model.chain, model.chain_params) if model.planar_reduced
                                   else None)  # as build_problem
    else:
        if result.tracker_frame is None:
            raise InputError(f"{campaign.source}: a point (tracker) campaign, but the result was identified from "
                             f"distances")
        meas = PointMeasurement(model, campaign.commands, campaign.dirs, campaign.points_mm, result.tracker_frame)
    cal = SerialCalibration(meas, SolverOptions(), find_gauge(meas), campaign.source, campaign.line)
    return cal, meas.start_vector()


# -- the result's own priors and budget (issue 23, item 4) ----------------------------------------------------------
@dataclass
class Priors:
    """The quadratic costs of an identification re-added to the program at a result (:func:`restore_priors`):
    ``Q`` (n, n) their Hessian over the program's parameters (None: the result had none), ``notes`` what was
    re-added (one line each)."""

    Q: Optional[np.ndarray]
    notes: list


def restore_priors(cal, result, x) -> Priors:
    """Re-add to ``cal.prog`` the quadratic costs the identification of ``result`` had, centred at the identified
    values ``x`` (a prior pulls the fit toward its centre; the propagation is about the spread around the
    estimate, so the centre is the estimate's):

    * the smoothness prior ½ λ ‖R x‖² of the maps when the result states one (``smoothing.weight``; R the
      roughness rows the loaded maps give, :meth:`~olti_drake.model.serial.SerialPositionModel.roughness`);
    * the ``--regularize`` priors ½ w (x − x̂)² the result records (``priors``: names, weights,
      :func:`~olti_drake.io.serial_io.program_priors`);
    * then, as the identification did, a prior of :func:`~olti_drake.estimation.serial_identification.prior_weight`
      on every parameter the program still cannot determine (a result that records no priors: written without
      its program, or by an older version) -- only when the result was regularized (its notes say so); else the
      campaign's own refusal (one line, by name).

    Without them the program of a regularized result is singular ("Singular matrix"), and one with a smoothness
    prior would be propagated as another estimator than the one that made the result."""
    from olti_drake.estimation.calibration import SMOOTHNESS_PRIOR, UnidentifiableError
    from olti_drake.estimation.serial_identification import prior_weight

    data, n = result.data, len(cal.names)
    Q = np.zeros((n, n))
    notes = []
    smoothing = data.get("smoothing")
    weight = smoothing.get("weight") if isinstance(smoothing, dict) else None
    if isinstance(weight, (int, float)) and not isinstance(weight, bool) and np.isfinite(weight) and weight > 0:
        rows = getattr(cal.measurement, "roughness", None)
        R = rows() if rows is not None else None
        if R is not None and R.shape[0]:
            P = float(weight) * np.asarray((R.T @ R).todense())
            _add_cost(cal, P, np.arange(n), x, SMOOTHNESS_PRIOR)
            Q += P
            notes.append(f"the result's smoothness prior re-added: weight {float(weight):.4g} "
                         f"({smoothing.get('method', '?')}) on the roughness of the maps")
    elif weight is not None and not (isinstance(weight, (int, float)) and weight == 0):
        raise InputError(f"key 'smoothing.weight' must be a number >= 0, got {weight!r}")
    for entry in data.get("priors") or []:
        names, weights = entry.get("names", []), entry.get("weights", [])
        if len(names) != len(weights):
            raise InputError("key 'priors': names and weights differ in length")
        unknown = [p for p in names if p not in cal.names]
        if unknown:
            raise InputError(f"key 'priors': {unknown[0]} is not a parameter of the result's program")
        idx = np.array([cal.names.index(p) for p in names], int)
        w = np.asarray(weights, float)
        if not np.all(np.isfinite(w) & (w >= 0)):
            raise InputError("key 'priors': weights must be finite and >= 0")
        _add_cost(cal, np.diag(w), idx, x, "prior (olti identify --regularize)")
        Q[idx, idx] += w
        notes.append(f"the result's {entry.get('kind', 'regularize')} priors re-added on {len(names)} parameter(s)")
    regularized = any(str(t).startswith("regularized") for t in data.get("notes", []))
    for _ in range(n):
        try:
            cal.check_identifiability(x)
            break
        except UnidentifiableError as e:
            names = [p for p in e.names if p in cal.names]
            if not regularized or not names:
                raise InputError(f"{cal.source}: at the result: {e}") from None
            idx = np.array([cal.names.index(p) for p in names], int)
            w = np.array([prior_weight(p) for p in names])
            _add_cost(cal, np.diag(w), idx, x, "prior (olti identify --regularize, rebuilt)")
            Q[idx, idx] += w
            notes.append(f"the result records no priors but was regularized: the identification's weak prior "
                         f"(estimation.serial_identification.prior_weight) re-added on {len(names)} parameter(s) "
                         f"the readings cannot determine")
    return Priors(Q if np.any(Q) else None, notes)


def _add_cost(cal, Q, idx, x, description):
    """½ (x − x̂)ᵀ Q (x − x̂) over the parameters ``idx`` of ``cal.prog`` (centred at ``x``)."""
    binding = cal.prog.AddQuadraticCost(Q, -Q @ x[idx], cal.variables[idx], is_convex=True)
    binding.evaluator().set_description(description)


def smoothing_priors(ident, x):
    """The fit's quadratic costs (the maps' smoothness prior at its weight, and each map's own roughness beyond it:
    :meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.smoothing_misfit`) as
    :class:`~olti_drake.estimation.serial_uncertainty.Priors` over the identification's parameters."""
    n = len(x)
    Q = ident.quadratic_costs()[0][:n, :n]
    if not np.any(Q):
        return Priors(None, [])
    notes = ["the result's smoothness prior: its own spread added (a pseudo-reading of the readings' variance, as "
             "weighed in the identification); the weight is the result's, not chosen again per trial"]
    D = ident.smoothing_misfit()
    if D is not None:  # (the maps rougher than the common weight says: their own prior variance in the spread)
        Q = Q.copy()
        Q[:D.shape[0], :D.shape[0]] += D[:n, :n]
        notes.append("each map's own roughness (the result's group weights) in that spread, as in the "
                     "identification's covariance")
    return Priors(Q, notes)


def prior_spread(cal, x, priors: Priors, reading_variance_mm2: float, cov=None, samples=None, seed: int = 0):
    """The priors' own uncertainty added to a propagation through the program (which holds their centres fixed):
    each quadratic prior is a pseudo-reading weighed as the identification weighed it, with the budget's reading
    variance ū² (mm²) -- the term B (ū² Q) B beside B Jᵀ diag(u²) J B (B the program's solution map; for a
    uniform budget the sum is ū² (JᵀJ + Q)⁻¹ within the gauge, the covariance the identification reports).
    Without it a parameter only a prior determines would get u ≈ 0.

    ``cov`` (n, n) linear: returns cov + B ū² Q B. ``samples`` (T, n) Monte Carlo: returns the samples plus B g_t,
    g_t ~ N(0, ū² Q) seeded (the prior's centre drawn per trial, to first order)."""
    from olti_drake.estimation.uncertainty import _solution_map

    if priors.Q is None:
        return cov if samples is None else samples
    n = len(x)
    B = _solution_map(cal, x)[0]
    G = reading_variance_mm2 * priors.Q[:n, :n]
    if samples is None:
        return cov + B @ G @ B
    from olti_drake.model.propagation import psd_sqrt

    rng = np.random.default_rng([seed, 23])
    g = rng.standard_normal((len(samples), n)) @ psd_sqrt(G)  # (symmetric: row order does not change the draws)
    return samples + g @ B.T


class CoordinateErrors:
    """A budget's reading errors (:class:`~olti_drake.model.budget.ReadingErrors`) for a point (tracker)
    campaign: every measured point has three residual rows (x, y, z), each with the reading's error at that
    point's distance from the tracker, independent -- the shapes the linear propagation and the Monte Carlo need
    (3 M rows for M points)."""

    def __init__(self, errors):
        self.errors = errors
        self.budget = errors.budget

    def std(self, distance_mm) -> np.ndarray:
        return np.repeat(np.asarray(self.errors.std(distance_mm), float).reshape(-1), 3)

    def draw(self, rng, distance_mm, trials: int) -> np.ndarray:
        return self.errors.draw(rng, np.repeat(np.asarray(distance_mm, float).reshape(-1), 3), trials)


def result_budget(result, name: str = "result", cal=None, x=None):
    """(budget, what) the robot of ``result`` is propagated with when no ``--budget`` is given: the SCARA of 000
    (the shipped ``scara`` model) its Table 2; any other robot the reading uncertainty of its own identification
    -- the one the result's covariance (and its predictions' u) rests on. With the result's stored covariance C
    and its program ``cal`` at ``x`` (priors re-added, :func:`restore_priors`): s² = the median over the parameters
    of diag(C) / diag(B (JᵀJ + Q) B), the covariance per unit reading variance (so exactly the identification's
    residual variance: its degrees of freedom, a smoothing's effective parameters and held-out scale included);
    else the residual standard deviation s = RMS(r) sqrt(m / (m − p)) of its m residuals and p parameters (the
    smoothing prior's effective parameters when it had one, times its ``u_scale``). Never another robot's
    budget."""
    from olti_drake.model.budget import Budget, Contributor, paper000_budget

    data = result.data
    if str(data.get("robot", {}).get("file", "")).lower() == "scara":
        return paper000_budget(), "built-in paper 000 Table 2 (the SCARA's)"
    s = _covariance_sigma(result, cal, x) if cal is not None and result.covariance is not None else None
    if s is not None:
        what = (f"the identification's own reading uncertainty: {1e3 * s:.3f} um (k = 1), the residual standard "
                f"deviation its covariance was formed with")
        return Budget(name="residual of the identification", source=f"{name}: {what}",
                      contributors=[Contributor("s", "residual standard deviation of the identification",
                                                1e3 * s, "um", 1.0, "A", "reading")]), what
    rms = float(data.get("residual_rms_mm", 0.0))
    m = int(data.get("n_readings", 0)) * (3 if result.tracker_frame is not None else 1)
    cov = data.get("covariance") or {}
    p = len(cov.get("names", [])) or len(result.model.names)
    smoothing = data.get("smoothing")
    if isinstance(smoothing, dict) and isinstance(smoothing.get("effective_parameters"), (int, float)):
        p = float(smoothing["effective_parameters"])
    s = rms * np.sqrt(m / max(m - p, 1.0)) if m else rms
    scale = smoothing.get("u_scale", 1.0) if isinstance(smoothing, dict) else 1.0
    scale = float(scale) if isinstance(scale, (int, float)) and np.isfinite(scale) and scale >= 1.0 else 1.0
    s *= scale  # (the smoothing's cross-validation found the held-out readings wider: the result's u holds it too)
    if not (np.isfinite(s) and s > 0):
        raise InputError(f"{name}: no reading uncertainty to propagate (residual RMS {rms:g} mm): give --budget")
    what = (f"the identification's own reading uncertainty: residual standard deviation {1e3 * s:.3f} um "
            f"(k = 1; RMS {1e3 * rms:.3f} um over {m} residuals, {p:.1f} parameters"
            + (f", times the smoothing's held-out scale {scale:.3g}" if scale > 1.0 else "") + ")")
    budget = Budget(name="residual of the identification", source=f"{name}: {what}",
                    contributors=[Contributor("s", "residual standard deviation of the identification",
                                              1e3 * s, "um", 1.0, "A", "reading")])
    return budget, what


def _covariance_sigma(result, cal, x):
    """s (mm) with C = s² B (JᵀJ + Q) B: the reading standard deviation the result's covariance C was formed with
    (median over the parameters the readings or priors determine), or None when not defined."""
    from olti_drake.estimation.uncertainty import _solution_map

    B, J = _solution_map(cal, x)
    Q = cal.quadratic_costs()[0][:len(x), :len(x)]
    unit = np.einsum("ij,jk,ki->i", B, (J.T @ J).toarray() + Q, B)
    C = result.covariance_of(cal.names)
    if C is None:
        return None
    own = np.diag(C)
    ok = unit > 1e-12 * max(float(unit.max()), 1e-300)
    if not ok.any():
        return None
    s2 = float(np.median(own[ok] / unit[ok]))
    return float(np.sqrt(s2)) if np.isfinite(s2) and s2 > 0 else None


def zero_held_uncertainties(out: dict, measurement) -> dict:
    """Set the uncertainty of every held coordinate of ``out`` (an uncertainty layout, and its ``expanded``) to 0.

    A planar robot holds its stations' height and the tool offset along the plane's normal: they are not
    parameters, yet the layout writes the held values where a free coordinate's u goes (the same layout
    serves values and uncertainties)."""
    model = measurement.model
    held_tool = [k for k, t in enumerate(("tool_x_mm", "tool_y_mm", "tool_z_mm")) if t in model.held_tool]
    axis = getattr(measurement, "held_axis", None)
    for block in (out, out.get("expanded", {})):
        for k in held_tool:
            block["tool_offset_mm"][k] = 0.0
        if axis is not None and "stations_mm" in block:
            for row in block["stations_mm"]:
                row[axis] = 0.0
    return out


def reading_measurement(result, commands, dirs, station, time_s=None):
    """The :class:`~olti_drake.model.serial.DistanceMeasurement` of a result's stations (those ``station`` names,
    (M,) labels) for readings at ``commands`` / ``dirs`` (zero readings: its residual is the predicted reading),
    at the identified values; ``time_s`` (M,) for a result with a dead-path drift. As :func:`calibration_at_result`
    builds it for the result's own campaign."""
    from olti_drake.model.chain import robot_plane
    from olti_drake.model.serial import DistanceMeasurement

    model, data = result.model, result.data
    station = np.asarray(station, int)
    labels = np.unique(station)
    where = {int(j): i for i, j in enumerate(result.station_labels)}
    idx = np.array([where[int(j)] for j in labels], int)
    drift = "drift_mm_per_h" in data
    pick = (lambda key: np.asarray(data[key], float)[idx]) if drift else (lambda key: None)
    return DistanceMeasurement(model, commands, dirs, station, np.zeros(len(station)), result.stations_mm[idx],
                               result.dead_paths_mm[idx],
                               time_h=np.asarray(time_s, float) / 3600.0 if drift else None,
                               drift_mm_per_h=pick("drift_mm_per_h"), drift_reference_h=pick("drift_reference_h"),
                               plane=robot_plane(model.chain, model.chain_params) if model.planar_reduced else None)


def predicted_reading_std(result, commands, dirs, station, time_s=None):
    """(predicted readings (M,) mm, their u (M,) mm (k = 1) or None): ‖p − P_j‖ − d0_j of every row by the result,
    and sqrt(diag(J C Jᵀ)) with J the reading's Jacobian over the model's and the stations' parameters (station
    position, dead path, drift: :meth:`~olti_drake.model.serial.DistanceMeasurement.residuals`) and C the result's
    stored covariance over them, with the result's lack of fit added in quadrature; u None when the result stores
    no covariance."""
    meas = reading_measurement(result, commands, dirs, station, time_s)
    x = meas.start_vector()
    r, J = meas.residuals(x)
    C = result.covariance_of(meas.names)
    return r, (None if C is None else with_lack_of_fit(predicted_std(J, C), result.lack_of_fit_mm))


def predicted_point_std(result, commands, dirs):
    """(tool points (M, 3) mm, their u (M, 3) mm (k = 1) or None) by the result's model and stored covariance
    (:func:`tool_point_uncertainty`, each coordinate's u with the result's lack of fit added in quadrature); u None
    when the result stores no covariance."""
    model = result.model
    C = result.covariance_of(model.names)
    if C is None:
        return model.positions(commands, dirs), None
    p, u = tool_point_uncertainty(model, commands, dirs, cov=C)
    return p, with_lack_of_fit(u, result.lack_of_fit_mm)


def workspace_uncertainty(model, n_poses: int = 400, seed: int = 0, cov=None, samples=None) -> dict:
    """Predicted tool points and their u over seeded workspace poses (uniform in the model's commanded
    ranges, random approach directions for bidirectional maps): {poses_deg, dirs, points_mm, u_mm (M, 3),
    u_norm_mm (M,)} -- u_norm = ‖u‖ = sqrt(u_x² + u_y² + u_z²)."""
    rng = np.random.default_rng(seed)
    ranges = model.command_ranges()
    q = rng.uniform(ranges[:, 0], ranges[:, 1], size=(n_poses, len(ranges)))
    dirs = rng.choice([-1.0, 1.0], size=q.shape) if model.bidirectional else None
    p, u = tool_point_uncertainty(model, q, dirs, cov=cov, samples=samples)
    return {"poses_deg": q, "dirs": dirs, "points_mm": p, "u_mm": u, "u_norm_mm": np.linalg.norm(u, axis=1)}
