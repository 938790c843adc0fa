"""The under-resolution check of a map model, one for every kind (issue 22: each capability built once; issue 24,
class 8: "uncertainty that is too small without a warning").

A map model (the error maps of an N-joint robot every ``grid_step_deg``, a five-axis machine's error motions every
``pitch_deg``, the volumetric B-splines on knots every ``knot_spacing_mm``) can only hold what its representation
holds. Its residual cannot tell: the budget's reading u is above the misfit of a too coarse representation, while
the stated u of the points it predicts (a fraction of it) is below. Here the campaign is identified again on a
finer representation of the same family (each kind's :class:`Finer`: half the grid step, the finest identifiable
knots), and the points the readings see (tool points at the campaign's commands) of the two fits are compared:
their difference d against the stated u of this fit and u_f of the finer one, per coordinate.

With the truth in the coarser family the two are nested fits of one truth: d has the variance u_f² − u² (the finer
fit's extra spread; Richardson's argument for a refinement). Beyond that, d is what the coarse representation
misses, an error of every point it predicts: ``excess`` = mean((d² − max(u_f² − u², 0)) / u²) is its mean square
over the stated u², and ``ratio`` = sqrt(excess) its RMS in units of u. Above :data:`RESOLUTION_RATIO` the
representation is too coarse for the data: every stated u is inflated by ``inflation`` = sqrt(1 + excess), the
factor that makes the u cover that error beside the noise, and the warning names the finer representation to
re-run with (whose own check says whether it is enough). Inflating rather than refusing: the fit is still the
best this representation gives, and its u is then honest about what it misses. The SCARA of 000 keeps its own
check (held-out readings at alternate nodes, 000 Eq. 8-9): its readings sit on the nodes, where a finer grid adds
nothing the readings show.
"""

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from olti_drake.errors import InputError

#: The check fires when the RMS of what the coarse representation misses (``ratio``) exceeds this share of the
#: stated u: an error of half the u or more, the u's own spread left aside.
RESOLUTION_RATIO = 0.5


@dataclass
class Finer:
    """A finer representation of a fit's model: its label (``finer``, e.g. "<= 250 mm knots", beside ``this``,
    the fit's own), the option that asks for it (``rerun``, e.g. "--knot-spacing-mm 250"), ``points()`` -- the
    campaign identified on it, as (p_f, u_f) (K, D) mm of the points compared, raising InputError when refused --
    and the keys the check's record carries besides (``extra``). ``why``: not possible (then no ``points``)."""

    this: str
    finer: str = ""
    rerun: str = ""
    points: Optional[Callable[[], tuple]] = None
    what: str = "tool points"
    extra: dict = field(default_factory=dict)
    why: str = ""


def resolution_check(p, u, finer: Finer) -> Optional[dict]:
    """The check of the fit whose compared points are p (K, D) mm with stated u (K, D) mm against the fit on
    ``finer``: the record the result stores (``resolution_check``) -- {method, done, targets, difference_rms_mm,
    difference_max_mm, u_rms_mm, difference_over_u_rms, ratio, threshold, resolved, inflation[, warning]} and
    ``finer.extra`` -- or {method, done: False, why} when the finer fit is not possible or refused; None when no
    point has a u (nothing to compare)."""
    method = f"refit on {finer.finer or 'a finer representation'} (this fit: {finer.this})"
    if finer.points is None:
        return {"method": method, "done": False, "why": finer.why, **finer.extra}
    p, u = np.asarray(p, float), np.asarray(u, float)
    method = (f"the campaign refitted on {finer.finer} (this fit: {finer.this}); the {finer.what} of the two compared "
              f"at its {len(p)} targets against their stated u")
    seen = u > 1e-9 * max(float(u.max()) if u.size else 0.0, 1e-300)  # (a point the gauge fixes: u = 0)
    if not seen.any():
        return None
    try:
        p_f, u_f = (np.asarray(a, float) for a in finer.points())
    except InputError as e:  # unidentifiable or refused on the finer representation: say so, do not fail
        return {"method": method, "done": False, "why": " ".join(str(e).split()), **finer.extra}
    d = p - p_f
    z2 = (d[seen] ** 2 - np.maximum(u_f[seen] ** 2 - u[seen] ** 2, 0.0)) / u[seen] ** 2
    excess = max(float(np.mean(z2)), 0.0)
    ratio, missed = float(np.sqrt(excess)), float(np.sqrt(np.mean((d[seen] / u[seen]) ** 2)))
    out = {"method": method, "done": True, **finer.extra, "finer": finer.finer, "targets": int(len(p)),
           "difference_rms_mm": float(np.sqrt(np.mean(d ** 2))), "difference_max_mm": float(np.abs(d).max()),
           "u_rms_mm": float(np.sqrt(np.mean(u[seen] ** 2))), "difference_over_u_rms": missed, "ratio": ratio,
           "threshold": RESOLUTION_RATIO, "resolved": ratio <= RESOLUTION_RATIO, "inflation": 1.0}
    if ratio > RESOLUTION_RATIO:
        g = float(np.sqrt(1.0 + excess))
        out["inflation"] = g
        out["warning"] = (
            f"under-resolution check: the {finer.what} of the fit on {finer.finer} differ from this fit's "
            f"({finer.this}) by RMS {1e3 * out['difference_rms_mm']:.2f} um, max {1e3 * out['difference_max_mm']:.2f} "
            f"um, {missed:.2f} x the stated u (RMS over the {len(p)} targets; beyond the two fits' own spread "
            f"{ratio:.2f} x u, above {RESOLUTION_RATIO:g}): the representation is too coarse for the data -- every "
            f"stated u (and the covariance) is inflated {g:.3g} x to cover it; re-run with {finer.rerun}")
    return out


def inflate(fit, check: Optional[dict]) -> None:
    """Apply ``check`` (:func:`resolution_check`) to ``fit`` (a :class:`~olti_drake.estimation.calibration.Fit`)
    in place: the record on ``fit.resolution``; with an inflation g above 1 the covariance and std scaled, the
    warning added, and of the fit's lack of fit e only what the inflation does not already add to the u kept:
    sqrt(max(e² − (g² − 1) u_rms², 0)), u_rms the compared points' RMS u -- one misfit, a representation too
    coarse, which both show, counted once at the larger of the two estimates."""
    if not check:
        return
    fit.resolution = check
    g = check.get("inflation", 1.0)
    if g <= 1.0:
        return
    from olti_drake.estimation.calibration import deferred_covariance

    cov = deferred_covariance(fit)  # (a large fit's matrix stays deferred until read)
    fit.covariance = (lambda: cov() * g * g) if callable(cov) else (None if cov is None else cov * g * g)
    fit.std = np.asarray(fit.std) * g
    fit.warnings = list(fit.warnings) + [check["warning"]]
    e = float(fit.lack_of_fit_mm or 0.0)
    if e:  # one misfit (a representation too coarse) counted once: the lack of fit beyond what the inflation adds
        added = (g * g - 1.0) * check["u_rms_mm"] ** 2
        rest = float(np.sqrt(max(e * e - added, 0.0)))
        fit.notes = [n for n in fit.notes if not n.startswith("lack of fit")] + [
            f"lack of fit: the residuals' {1e3 * e:.3g} um beyond the readings' u are the representation's misfit, "
            f"which the under-resolution check's inflation holds too (it adds {1e3 * np.sqrt(added):.3g} um RMS to "
            f"the compared points' u): " + (f"{1e3 * rest:.3g} um of it is added to the predicted u" if rest else
                                             "not added to the predicted u again")]
        fit.lack_of_fit_mm = rest


def summary_line(check: Optional[dict]) -> str:
    """The summary's line of a check record ("" without one)."""
    if not check:
        return ""
    if not check.get("done"):
        return f"  resolution check not possible: {check['why']}"
    return (f"  resolution check: the fit on {check['finer']} moves the tool points by RMS "
            f"{1e3 * check['difference_rms_mm']:.2f} um ({check['difference_over_u_rms']:.2f} x the stated u) -- "
            + ("resolved" if check["resolved"] else f"too coarse: u inflated {check['inflation']:.3g} x"))


def inflation_note(doc: dict) -> str:
    """What ``olti uncertainty`` says of a result ``doc`` whose u the check inflated ("" when it did not): its
    propagation holds the readings' errors alone, not the representation's misfit."""
    g = (doc.get("resolution_check") or {}).get("inflation", 1.0)
    if g <= 1.0:
        return ""
    return (f"the result's u carries the under-resolution check's inflation ({g:.3g} x, its representation too "
            f"coarse for the data); this propagation holds the readings' errors alone")
