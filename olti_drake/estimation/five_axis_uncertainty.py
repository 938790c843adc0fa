"""Uncertainty of a five-axis identification (issue 25, item 5): every location error and error-motion value, by
the linear method (JCGM 100) or Monte Carlo (JCGM 101) of :mod:`olti_drake.estimation.uncertainty`.

* :func:`identification_at_result` -- the identification program of an ``olti-machine5/1`` result on its own
  campaign (:class:`~olti_drake.estimation.five_axis.FiveAxisIdentification`), re-solved with the result's error
  model and its smoothness weight as given (not chosen again), checked to reproduce the result's values: its
  stations, nests and tracker frames are not stored with the precision the propagation needs, the fit restores
  them.
* :func:`reading_errors` -- the readings' errors the propagation draws or weighs: the budget's (mm of each reading
  kind, scaled as the mixed campaign's rows are: :class:`~olti_drake.model.displacements.CombinedMeasurement`), or
  without a budget the identification's own reading uncertainty s, the one its covariance was formed with
  (C = s² (JᵀJ + Q)⁻¹ within the gauge). The draws are made in an order of the readings that does not depend on
  the file's row order (:class:`CanonicalErrors`), so neither does a Monte Carlo result.
* :func:`~olti_drake.estimation.serial_uncertainty.smoothing_priors` -- the maps' smoothness prior of the fit as the
  ``Priors`` whose own spread :func:`~olti_drake.estimation.serial_uncertainty.prior_spread` adds (the propagation holds the prior's centre):
  with s, the linear method then gives the identification's covariance.

The Monte Carlo re-simulates the campaign's readings from the identified model (the readings at x̂) plus seeded
errors and re-solves each trial (:func:`~olti_drake.estimation.uncertainty.monte_carlo`). Units: mm, deg, µrad.
"""

import os
from types import SimpleNamespace

import numpy as np

from olti_drake.errors import InputError
from olti_drake.estimation.uncertainty import trial_tolerance
from olti_drake.estimation.five_axis import residual_rows  # noqa: F401  (the readings' rows, here since issue 25)

#: The re-solved model values must reproduce the result's within this share of their u (else: not its campaign).
REPRODUCE_U = 0.05


def result_options(doc: dict, name: str):
    """The :class:`~olti_drake.estimation.five_axis.FiveAxisOptions` of the identification that wrote the result
    ``doc`` (file ``name``): its model, grid and tool offsets, its smoothness weights as given (per map when it has
    them; or off), its
    linear axes: identified (on the result's knots), from its ``--linear`` volumetric result (the file relative to
    the result), or perfect (a result written before linear axes were identified by default)."""
    from olti_drake.estimation.five_axis import LINEAR_IDENTIFY, LINEAR_PERFECT, FiveAxisOptions

    settings = doc["error_model"]
    smoothing = doc.get("smoothing") or {}
    weight = smoothing.get("weight") if isinstance(smoothing, dict) else None
    per_map = smoothing.get("group_weights") if isinstance(smoothing, dict) else None
    linear = (doc.get("linear_from") or {}).get("file")
    if settings.get("linear") == LINEAR_IDENTIFY:
        linear = {"linear": LINEAR_IDENTIFY, "knot_spacing_mm": settings.get("knot_spacing_mm")}
    elif linear:
        linear = {"linear": linear if os.path.isabs(linear) else os.path.join(os.path.dirname(os.path.abspath(name)),
                                                                              linear)}
    else:
        linear = {"linear": LINEAR_PERFECT}
    return FiveAxisOptions(model=doc.get("model", "errormap"), pitch_deg=float(settings["pitch_deg"]),
                           tool_offsets_mm=settings.get("tool_offsets_mm"),
                           smoothing=("off" if not (isinstance(weight, (int, float)) and weight > 0) else
                                      {"weight": float(weight), "group_weights": dict(per_map)}
                                      if isinstance(per_map, dict) and per_map else float(weight)),
                           **linear)


def identification_at_result(res, campaign, result_path):
    """(identification, fit, note): the result ``res`` (:class:`~olti_drake.io.five_axis_io.Machine5Result`)
    re-solved on ``campaign`` (the :class:`~olti_drake.io.five_axis_io.FiveAxisCampaign` it came from, digest
    checked; ``note`` says when the result carries no digest) with :func:`result_options`, the same held groups.
    Refused in one line when the campaign or the re-solved values are not the result's."""
    from olti_drake.estimation.five_axis import FiveAxisIdentification
    from olti_drake.io.csvio import check_campaign_matches

    doc, name = res.document, str(result_path)
    note = check_campaign_matches(doc, SimpleNamespace(digest=lambda: campaign.digest, source=campaign.source), name)
    settings = doc["error_model"]
    ident = FiveAxisIdentification(campaign, res.machine, result_options(doc, name))
    mine = ident.error_model_settings()
    differ = [k for k in settings if k in mine and mine[k] != settings[k]]
    if differ or set(ident.dropped) != set(res.held):
        what = (f"error model '{differ[0]}' {mine[differ[0]]!r}, the result's {settings[differ[0]]!r}" if differ else
                f"held {sorted(ident.dropped)}, the result {sorted(res.held)}")
        raise InputError(f"{campaign.source}: not the campaign of {name}: its identification has {what}")
    fit = ident.solve()
    _check_reproduced(ident, fit, res, name)
    ident.trial_tolerance = trial_tolerance(fit)  # (a millionth of each u: estimation.uncertainty)
    return ident, fit, note


def _check_reproduced(ident, fit, res, name) -> None:
    """Refuse when the re-solved model values differ from the result's by more than :data:`REPRODUCE_U` u."""
    n = ident.position_model.n_params
    if tuple(ident.names[:n]) != tuple(res.names):
        raise InputError(f"{name}: its parameters are not those its campaign identifies (another version's result?)")
    z = np.abs(fit.x[:n] - res.x) / np.maximum(fit.std[:n], 1e-12)
    worst = int(np.argmax(z))
    if z[worst] > REPRODUCE_U:
        raise InputError(f"{name}: re-solved on its campaign, {res.names[worst]} is {z[worst]:.3g} u from the "
                         f"result's value (at most {REPRODUCE_U:g} u): not this campaign's result, or its options "
                         f"(loss, solver) were not the defaults")


class CanonicalErrors:
    """Reading errors (:class:`~olti_drake.model.budget.ReadingErrors`) of the rows of a measurement, each row's
    times ``scale[row]`` (the mixed campaign's row scaling; 1 otherwise), drawn in the order ``order`` (rows by
    content, :func:`~olti_drake.io.five_axis_io.canonical_rows`): a Monte Carlo on the campaign's rows in another file order draws the same
    error for the same reading."""

    ordered_by_content = True  # (uncertainty._draw_by_content: this order is already the rows' content)

    def __init__(self, errors, order, scale):
        self.errors, self.order, self.scale = errors, np.asarray(order, int), np.asarray(scale, float)
        self.budget = errors.budget

    def std(self, distance_mm) -> np.ndarray:
        return self.scale * np.asarray(self.errors.std(distance_mm), float).reshape(-1)

    def draw(self, rng, distance_mm, trials: int) -> np.ndarray:
        D = np.broadcast_to(np.asarray(distance_mm, float).reshape(-1), self.order.shape)
        out = np.empty((trials, self.order.size))
        out[:, self.order] = self.errors.draw(rng, D[self.order], trials)
        return out * self.scale


def identification_sigma(ident, fit) -> float:
    """s (mm of the campaign's first reading kind) with the fit's covariance C = s² B (s² (B + B D B) with each
    map's own roughness D, :meth:`~olti_drake.estimation.calibration.LeastSquaresProgram.smoothing_misfit`),
    B = (JᵀJ + Q)⁻¹ within the gauge (:func:`~olti_drake.estimation.uncertainty._solution_map`): the reading
    uncertainty the identification formed its u with (its residuals' σ over the readings less the parameters they
    determine, the smoothing's floor)."""
    from olti_drake.estimation.uncertainty import _solution_map
    from olti_drake.model.propagation import predicted_variance

    B = _solution_map(ident, fit.x)[0]
    known = held_out_covariance(ident, fit.x)  # (--linear, the maps' representation: not the readings' part)
    D = ident.smoothing_misfit()  # (each map's own roughness: C = s² (B + B D B))
    unit = np.diag(B) if D is None else np.diag(B) + predicted_variance(B[:, :len(D)], D)  # (diag(B D B))
    own = np.diag(fit.covariance - (0.0 if known is None else known))
    ok = unit > 1e-12 * max(float(unit.max()), 1e-300)
    s2 = float(np.median(own[ok] / unit[ok])) if ok.any() else float("nan")
    if not (np.isfinite(s2) and s2 > 0):
        raise InputError(f"{ident.source}: no reading uncertainty to propagate (the fit's covariance is 0): give "
                         f"--budget")
    return float(np.sqrt(s2))


def reading_errors(ident, fit, budget=None):
    """(errors for the propagation, the budget, a sentence saying which): the ``budget``'s (its reading
    uncertainty in mm of each reading kind, the rows scaled as the identification weighs them) or, when None,
    a one-contributor budget of the identification's own reading uncertainty (:func:`identification_sigma`)."""
    from olti_drake.model.budget import Budget, Contributor, ReadingErrors

    rows, coord = residual_rows(ident)
    from olti_drake.io.five_axis_io import canonical_rows

    rank = canonical_rows(ident.campaign)
    order = np.lexsort((coord, rank[rows]))
    if budget is None:
        s = identification_sigma(ident, fit)
        what = (f"the identification's own reading uncertainty {1e3 * s:.3f} um (k = 1), the one its covariance was "
                f"formed with")
        budget = Budget(name="residual of the identification", source=what, contributors=[
            Contributor("s", "reading uncertainty of the identification", 1e3 * s, "um", 1.0, "A", "reading")])
        scale = np.ones(rows.size)  # (s is already in the units of the weighed rows)
    else:
        what = f"budget {budget.name!r}"
        meas = ident.measurement
        scale = np.concatenate([np.full(s.stop - s.start, k) for s, k in zip(meas.row_slices, meas.scales)])
    return CanonicalErrors(ReadingErrors(budget), order, scale), budget, what


def linear_axes_covariance(ident, x):
    """The covariance (n, n) the linear axes of an earlier volumetric result (``olti identify --linear``) add to
    the estimate, as the identification states it (S C_θ Sᵀ: the volumetric result's own covariance, held fixed in
    the fit), or None without them."""
    if getattr(ident, "linear_from", None) is None:
        return None
    return ident._linear_covariance(x)


def held_out_covariance(ident, x):
    """What the identification's covariance holds beyond the readings' errors and the prior (n, n), or None: the
    linear axes' (:func:`linear_axes_covariance`) plus the maps' representation on their grid
    (:meth:`~olti_drake.estimation.five_axis.FiveAxisIdentification.representation`), as the fit added them."""
    parts = [linear_axes_covariance(ident, x)]
    if getattr(ident, "errors", None) is not None and ident.errors.maps:
        parts.append(ident.representation(x)[0])
    parts = [C for C in parts if C is not None]
    return sum(parts) if parts else None


def with_prior_spread(ident, x, errors, std, cov, samples, every, seed: int = 0):
    """(std, samples for intervals or None, notes): a propagation's result (:func:`olti_drake.cli.propagate.
    propagate`: ``cov`` linear, or ``every`` Monte Carlo sample and ``samples`` those for intervals) with what the
    readings' errors do not hold added: the smoothness prior's own spread
    (:func:`~olti_drake.estimation.serial_uncertainty.prior_spread`, the readings' mean variance ū²) and the linear
    axes' of ``--linear`` (:func:`linear_axes_covariance`; Monte Carlo: seeded normal draws of it). Unchanged
    without either."""
    from olti_drake.estimation.serial_uncertainty import prior_spread

    from olti_drake.estimation.serial_uncertainty import smoothing_priors

    priors, known = smoothing_priors(ident, x), held_out_covariance(ident, x)
    notes = list(priors.notes)
    if getattr(ident, "linear_from", None) is not None:
        notes.append("the linear axes' uncertainty (the --linear volumetric result's covariance, held fixed in the "
                     "fit) added, as the identification states it")
    if ident.errors.maps:
        notes.append("the maps' representation on their grid (a bubble between nodes, FiveAxisIdentification."
                     "representation) added, as the identification states it")
    if priors.Q is None and known is None:
        return std, samples, notes
    u2 = float(np.mean(errors.std(ident.beam_lengths(x)) ** 2))
    if cov is not None:
        cov = prior_spread(ident, x, priors, u2, cov=cov) + (0.0 if known is None else known)
        return np.sqrt(np.maximum(np.diag(cov), 0.0)), samples, notes
    every = prior_spread(ident, x, priors, u2, samples=every, seed=seed)
    if known is not None:
        from olti_drake.model.propagation import psd_sqrt

        rng = np.random.default_rng([seed, 25])
        every = every + rng.standard_normal(every.shape) @ psd_sqrt(known)
    return every.std(axis=0, ddof=1), (every if samples is not None else None), notes


def tool_point_u(ident, fit, commands, directions=None, tool=None):
    """(tool points (M, 3), their u (M, 3)) mm, k = 1, workpiece frame, at ``commands`` (mm, deg) on the fit of
    ``ident`` (:class:`~olti_drake.estimation.five_axis.FiveAxisIdentification`): the covariance propagated
    (:func:`~olti_drake.model.propagation.predicted_std`) and the fit's lack of fit added in quadrature
    (:func:`~olti_drake.model.propagation.with_lack_of_fit`) -- as ``olti predict`` does."""
    from olti_drake.model.propagation import with_lack_of_fit
    from olti_drake.model.five_axis_errors import FiveAxisPositionModel
    from olti_drake.model.propagation import predicted_std

    pm = FiveAxisPositionModel(ident.machine, ident.errors, commands, directions, tool, frame="workpiece",
                               held=ident.position_model.held)
    k = pm.n_params
    p, J = pm.jacobian(fit.x[:k])
    u = predicted_std(J.tocsr(), np.asarray(fit.covariance)[:k, :k], dim=3)
    return p, with_lack_of_fit(u, getattr(fit, "lack_of_fit_mm", 0.0))
