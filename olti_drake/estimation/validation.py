"""Model selection a user can trust: K-fold cross-validation by pose of an N-joint robot's candidate models.

:func:`cross_validate` identifies each candidate model (geometric ``dh``; error maps at several grid steps;
compliance; drift) on K − 1 folds of a campaign's poses with the library's own identification
(:func:`~olti_drake.estimation.serial_identification.serial_problem` /
:func:`~olti_drake.estimation.serial_identification.identify_serial`, every identify option carried over by
``dataclasses.replace``), predicts the held-out fold's readings with the identified measurement, and states each
model's held-out RMS with its spread and the recommended model.

**Folds by pose.** A pose is the set of rows sharing the same commanded joint angles and (when the campaign has
them) approach directions: every row of a pose -- one per station, or the one tracker point -- lies in the same
fold, so a held-out pose is never half seen in training. The distinct pose keys are sorted (lexicographically,
``numpy.unique``), permuted by ``numpy.random.default_rng(seed).permutation`` and dealt round-robin into the K
folds (sizes differ by at most one pose): the assignment depends on the set of poses and the seed only, never on
the order of the rows.

**Held-out prediction.** Distance rows: ‖p − P_j‖ − d0_j (minus the drift v_j·(t − t̄_j) when identified, t̄_j
the training rows' mean time) by the identified tool point p and the identified station P_j and dead path d0_j;
tracker rows: R p + t by the identified tracker frame. A held-out command beyond a training map's grid (the
training poses did not reach it) holds the end node's value (``clamp``, as ``olti predict --outside clamp``):
counted per fold (``clamped_readings``, ``clamped_poses``). The metric: RMS of the held-out distance residuals
(mm) for distance campaigns, RMS of the held-out 3D point errors ‖R p + t − m‖ (mm) for tracker campaigns.
Fits are solutions only (``Calibration.fit(uncertainty=False)``: no covariance); a fold whose model the library
rebuilds after its first fit (a tool point on a joint axis at the start, a planar robot's stations off its
plane) is rebuilt by the library's own refinement, whose fits carry their uncertainty (no option there).

**The rule** (:data:`RULE`): models refused in any fold are not recommended (the refusal is stated with its
reason); among the others the lowest mean held-out RMS wins, unless a model with fewer parameters has a mean
within one standard error of it (se = sample std over the folds / √K): then the one with the fewest parameters
among those within (the one-standard-error rule).

**The document** (CV.json, :func:`cross_validate`'s dict; mm):

* ``format`` ``"olti-cv/1"``, ``kind`` ``"serial"``;
* ``campaign``: ``file``, ``kind`` (distance | point), ``readings``, ``poses``, ``sha256`` (its valid
  readings' digest), ``time_s`` (whether it has the column);
* ``folds`` K, ``seed``, ``fold_assignment`` (the sentence above), ``fold_poses`` and ``fold_readings``
  (per fold, the held-out counts);
* ``metric``: what the RMS is of;
* ``rule``: :data:`RULE`;
* ``models``: one object per candidate, in the order given: ``name`` (``dh``, ``errormap:15``,
  ``dh+compliance``, ``dh+drift``, ...), ``model``, ``grid_step_deg`` (null for dh), ``compliance``,
  ``drift``, ``parameters`` (unknowns of its fits, the median over the folds, stations or frame included),
  ``mean_rms_mm``, ``std_rms_mm`` (sample std over the folds), ``se_rms_mm`` (std / √K), ``fold_rms_mm`` (per
  fold; null where refused), ``train_rms_mm`` (the fit's residual RMS per fold, same metric), ``n_refused``,
  ``refused`` ([{``fold``, ``reason``}], the library's one-line refusal), ``clamped_readings``,
  ``clamped_poses`` (held-out readings/poses with a command beyond the fold's map grid, summed over the folds),
  ``seconds``; mean/std/se are null when any fold was refused;
* ``recommended``: a model name or null (every candidate refused); ``reason``: one sentence why;
* ``options``: the identify options every candidate carried (loss, solver, tool offset, ...).

Units: mm and degrees.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from olti_drake import formats
from olti_drake.errors import InputError

FORMAT = formats.CROSS_VALIDATION
#: The candidates when none are named: the geometric model, maps at three grid steps, compliance (where the
#: robot's gravity torques vary over the campaign), drift (distance campaigns with ``time_s``).
DEFAULT_MODELS = ("dh", "errormap:30", "errormap:15", "errormap:7.5", "dh+compliance", "dh+drift")
RULE = ("one-standard-error rule: among the models fitted in every fold, the lowest mean held-out RMS; a model "
        "with fewer parameters whose mean is within one standard error (sample std over the folds / sqrt(K)) of "
        "that lowest mean is preferred, the fewest parameters first; a model refused in any fold is not recommended")
ASSIGNMENT = ("by pose (rows with the same commanded angles and directions stay together): the sorted distinct "
              "poses permuted by numpy.random.default_rng(seed) and dealt round-robin into the folds")
MODIFIERS = ("compliance", "drift")


@dataclass(frozen=True)
class Candidate:
    """One model to validate: ``model`` dh | errormap, its grid step (deg, errormap), compliance, drift."""

    model: str
    grid_step_deg: Optional[float] = None
    compliance: bool = False
    drift: bool = False

    @property
    def name(self) -> str:
        base = "dh" if self.model == "dh" else f"errormap:{self.grid_step_deg:g}"
        return base + "".join(f"+{m}" for m in MODIFIERS if getattr(self, m))


def parse_models(text, default_step: float = 15.0) -> List[Candidate]:
    """Candidates from ``dh,errormap:30,errormap,dh+compliance,drift`` (a text or a sequence of names).

    ``base[:STEP][+compliance][+drift]``: base ``dh`` or ``errormap`` (``errormap`` alone: ``default_step``,
    deg); ``compliance`` and ``drift`` alone mean ``dh+compliance`` and ``dh+drift``. Bad names: one line."""
    items = [t.strip() for t in (text.split(",") if isinstance(text, str) else text)]
    if not items or any(not t for t in items):
        raise InputError(f"--models: expected a comma list such as dh,errormap:30,errormap:15, got {text!r}")
    out = []
    for item in items:
        parts = [p.strip() for p in item.split("+")]
        if parts[0] in MODIFIERS:
            parts.insert(0, "dh")
        base, _, step = parts[0].partition(":")
        mods = parts[1:]
        bad = [m for m in mods if m not in MODIFIERS]
        if base not in ("dh", "errormap") or bad or len(set(mods)) != len(mods):
            raise InputError(f"--models: unknown model {item!r} (models: dh, errormap, errormap:STEP_DEG, "
                             f"compliance, drift, or a base with +compliance / +drift, e.g. errormap:15+drift)")
        if base == "dh" and step:
            raise InputError(f"--models: {item!r}: dh has no grid step (errormap:STEP_DEG has)")
        grid = None
        if base == "errormap":
            try:
                grid = float(step) if step else float(default_step)
            except ValueError:
                grid = float("nan")
            if not (math.isfinite(grid) and 0 < grid <= 360):
                raise InputError(f"--models: {item!r}: the grid step must be a number of degrees in (0, 360]")
        out.append(Candidate(base, grid, "compliance" in mods, "drift" in mods))
    names = [c.name for c in out]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"--models: {twice[0]} is named twice")
    return out


# -- folds ----------------------------------------------------------------------------------------------------------
def pose_keys(campaign):
    """(sorted distinct pose keys (P, N or 2N), pose index of every row (M,)): a pose = commands (+ dirs)."""
    key = campaign.commands if campaign.dirs is None else np.hstack([campaign.commands, campaign.dirs])
    unique, inverse = np.unique(np.asarray(key, float), axis=0, return_inverse=True)
    return unique, inverse.ravel()


def fold_of_rows(campaign, folds: int, seed: int = 0) -> np.ndarray:
    """The fold (0..K-1) of every row: by pose, seeded over the sorted pose keys (module doc), so independent of
    the order of the rows. Refuses (one line) K < 2 or K beyond the number of poses."""
    unique, inverse = pose_keys(campaign)
    n = len(unique)
    if isinstance(folds, bool) or int(folds) != folds or folds < 2:
        raise InputError(f"--folds: {folds!r}: cross-validation needs at least 2 folds")
    if folds > n:
        raise InputError(f"--folds {folds}: {campaign.source} has {n} distinct poses; give at most {n} folds")
    order = np.random.default_rng(seed).permutation(n)
    fold_of_pose = np.empty(n, dtype=int)
    fold_of_pose[order] = np.arange(n) % int(folds)
    return fold_of_pose[inverse]


# -- one fold -------------------------------------------------------------------------------------------------------
def fit_solution(chain, campaign, options):
    """The identification of ``campaign`` as :func:`identify_serial` does it, the first fit a solution only
    (``Calibration.fit(uncertainty=False)``); the library's own refinement after it
    (``serial_identification._refined``: the model rebuilt around the fitted tool point when the start's lies on a
    joint axis, a planar robot's stations off its plane on their sides) as the library runs it. Raises the
    library's one-line InputError when refused."""
    from olti_drake.estimation.serial_identification import _refined, serial_problem

    cal, finish = serial_problem(chain, campaign, options)
    cal.fit = functools.partial(type(cal).fit, cal, uncertainty=False)  # (this program only)
    return _refined(chain, campaign, options, finish())


def _clamped_model(model):
    """The identified model whose maps hold their end values beyond their grids (``outside='clamp'``)."""
    from olti_drake.model.serial import JointMap

    if not model.maps:
        return model
    out = model.with_vector(model.start_vector())
    out.maps = tuple(JointMap(dataclasses.replace(m.emap, outside="clamp"), m.bidirectional) for m in out.maps)
    return out


def _outside(model, commands) -> np.ndarray:
    """(M,) rows with a mapped joint's command beyond its map's grid."""
    from olti_drake.model.errormap import GRID_TOLERANCE_DEG as tol

    out = np.zeros(len(commands), dtype=bool)
    for j, m in zip(model.map_joints, model.maps):
        g = m.emap.grid_deg
        out |= (commands[:, j] < g[0] - tol) | (commands[:, j] > g[-1] + tol)
    return out


def predict_rows(ident, held):
    """The held-out campaign's readings by the identification: (M,) distances mm, or (M, 3) tracker points mm;
    and (M,) the rows whose command lies beyond a map's grid (clamped)."""
    from olti_drake.model.measurements import distance_residual
    from olti_drake.model.serial import PointMeasurement

    meas, x = ident.measurement, ident.fit.x
    model = _clamped_model(meas.model)
    xm = x[:model.n_params]
    clamped = _outside(model, held.commands)
    if held.kind == "point":
        own = x[model.n_params:]
        pm = PointMeasurement(model, held.commands, held.dirs, held.points_mm, own)
        return pm.predict(np.concatenate([xm, own])), clamped
    lay = meas.layout(x)
    labels = list(meas.labels)
    missing = sorted(set(np.unique(held.station)) - set(labels))
    if missing:
        raise InputError(f"station {missing[0]} has no reading in the training folds")
    idx = np.array([labels.index(s) for s in held.station], dtype=int)
    P = np.asarray(lay["stations_mm"], float)[idx]
    d0 = np.asarray(lay["dead_paths_mm"], float)[idx]
    if meas.time_h is not None:
        d0 = d0 + np.asarray(lay["drift_mm_per_h"], float)[idx] * (held.time_s / 3600.0
                                                                    - meas.drift_reference_h[idx])
    p = model.positions(held.commands, held.dirs, xm)
    return distance_residual(p, P, d0, 0.0)[0], clamped


def _rms(e) -> float:
    e = np.asarray(e, float)
    return float(np.sqrt(np.mean(np.sum(e.reshape(len(e), -1) ** 2, axis=1)))) if len(e) else float("nan")


def _train_rms(ident, kind) -> float:
    r = np.asarray(ident.fit.residuals, float)
    return _rms(r.reshape(-1, 3) if kind == "point" else r)


def _one_line(e: Exception, source: str) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text[len(source) + 2:] if text.startswith(f"{source}: ") else text


# -- the candidates -----------------------------------------------------------------------------------------------
def _compliant(chain, campaign) -> bool:
    from olti_drake.model.serial import build_position_model

    try:
        m = build_position_model(chain, campaign.commands, campaign.dirs, kind="dh", compliance=True)
    except (ValueError, RuntimeError):
        return False
    return len(m.compliance_joints) > 0


def _has_time(campaign) -> bool:
    return campaign.kind == "distance" and campaign.time_s is not None


def default_candidates(chain, campaign, options) -> List[Candidate]:
    """:data:`DEFAULT_MODELS` that apply: drift only where the campaign has ``time_s``, compliance only where a
    joint's gravity torque varies over the campaign (else it is the geometric model again)."""
    return [c for c in parse_models(DEFAULT_MODELS) if not (c.drift and not _has_time(campaign))
            and not (c.compliance and not (options.compliance or _compliant(chain, campaign)))]


def _candidates(chain, campaign, options, models):
    """[(Candidate, options for it)], deduplicated; the defaults that do not apply to the campaign left out."""
    has_time = _has_time(campaign)
    if options.drift and not has_time:
        raise InputError(f"{campaign.source}: --drift needs a distance campaign with a 'time_s' column (the time of "
                         f"every reading, s)")
    if models is None:
        wanted = default_candidates(chain, campaign, options)
    else:
        wanted = parse_models(models, options.grid_step_deg) if isinstance(models, str) or not all(
            isinstance(m, Candidate) for m in models) else list(models)
        drift = next((c for c in wanted if c.drift), None)
        if drift is not None and not has_time:
            raise InputError(f"--models {drift.name}: drift needs a distance campaign with a 'time_s' column "
                             f"({campaign.source} has none)")
    out, seen = [], set()
    for c in wanted:
        c = dataclasses.replace(c, compliance=c.compliance or bool(options.compliance),
                                drift=c.drift or bool(options.drift))
        if c.name in seen:
            continue
        seen.add(c.name)
        o = dataclasses.replace(options, model=c.model, compliance=c.compliance, drift=c.drift,
                                grid_step_deg=options.grid_step_deg if c.grid_step_deg is None else c.grid_step_deg)
        out.append((c, o))
    if not out:
        raise InputError("--models: no candidate model")
    return out


def _validate_one(chain, campaign, fold, k, candidate, options) -> dict:
    from olti_drake.estimation.serial_identification import check_serial_map_size

    t0 = time.perf_counter()
    rows = dict(fold_rms_mm=[], train_rms_mm=[], refused=[], parameters=[], clamped_readings=0, clamped_poses=0)
    try:
        check_serial_map_size(campaign, options)  # (a grid that would allocate gigabytes: before any work)
        too_large = None
    except InputError as e:
        too_large = _one_line(e, campaign.source)
    for f in range(k):
        if too_large is not None:
            rows["refused"].append({"fold": f, "reason": too_large})
            rows["fold_rms_mm"].append(None)
            rows["train_rms_mm"].append(None)
            continue
        train, held = campaign.subset(fold != f), campaign.subset(fold == f)
        try:
            ident = fit_solution(chain, train, options)
            pred, clamped = predict_rows(ident, held)
        except (InputError, np.linalg.LinAlgError) as e:
            rows["refused"].append({"fold": f, "reason": _one_line(e, campaign.source)})
            rows["fold_rms_mm"].append(None)
            rows["train_rms_mm"].append(None)
            continue
        truth = held.points_mm if held.kind == "point" else held.displacement_mm
        rows["fold_rms_mm"].append(_rms(pred - truth))
        rows["train_rms_mm"].append(_train_rms(ident, held.kind))
        rows["parameters"].append(len(ident.fit.names))
        rows["clamped_readings"] += int(np.sum(clamped))
        rows["clamped_poses"] += int(len(np.unique(pose_keys(held.subset(clamped))[0], axis=0))) if clamped.any() else 0
    ok = [v for v in rows["fold_rms_mm"] if v is not None]
    full = len(ok) == k
    std = float(np.std(ok, ddof=1)) if full else None
    return {"name": candidate.name, "model": candidate.model, "grid_step_deg": candidate.grid_step_deg,
            "compliance": candidate.compliance, "drift": candidate.drift,
            "parameters": int(np.median(rows["parameters"])) if rows["parameters"] else None,
            "mean_rms_mm": float(np.mean(ok)) if full else None, "std_rms_mm": std,
            "se_rms_mm": std / math.sqrt(k) if full else None,
            "fold_rms_mm": rows["fold_rms_mm"], "train_rms_mm": rows["train_rms_mm"],
            "n_refused": len(rows["refused"]), "refused": rows["refused"],
            "clamped_readings": rows["clamped_readings"], "clamped_poses": rows["clamped_poses"],
            "seconds": time.perf_counter() - t0}


def short_reason(reason: str, most: int = 110) -> str:
    """A refusal's cause without its hint (after `` -- ``), at most ``most`` characters."""
    head = reason.split(" -- ")[0]
    return head if len(head) <= most else head[:most - 3].rstrip(" ,") + "..."


def recommend(models: Sequence[dict]):
    """(name or None, reason) by :data:`RULE` over :func:`cross_validate`'s model objects."""
    fitted = [m for m in models if m["n_refused"] == 0 and m["mean_rms_mm"] is not None]
    refused = [m for m in models if m["n_refused"]]
    said_refused = ("; " + "; ".join(f"{m['name']} refused in {m['n_refused']} of {len(m['fold_rms_mm'])} folds "
                                     f"({short_reason(m['refused'][0]['reason'])})" for m in refused)) if refused else ""
    if not fitted:
        return None, "no candidate was fitted in every fold" + said_refused
    best = min(fitted, key=lambda m: m["mean_rms_mm"])
    bound = best["mean_rms_mm"] + best["se_rms_mm"]
    within = [m for m in fitted if m["mean_rms_mm"] <= bound]
    pick = min(within, key=lambda m: (m["parameters"], m["mean_rms_mm"]))
    if pick is best:
        why = (f"{best['name']} has the lowest mean held-out RMS, {best['mean_rms_mm']:.4g} mm (standard error "
               f"{best['se_rms_mm']:.2g} mm)"
               + ("" if len(fitted) == 1 else ", and no model with fewer parameters is within one standard error of it"))
    else:
        why = (f"{best['name']} has the lowest mean held-out RMS, {best['mean_rms_mm']:.4g} +- "
               f"{best['se_rms_mm']:.2g} mm (standard error), but {pick['name']} is within one standard error of "
               f"it ({pick['mean_rms_mm']:.4g} mm) with {pick['parameters']} instead of {best['parameters']} "
               f"parameters: the simpler model")
    return pick["name"], why + said_refused


def _options_dict(options) -> dict:
    out = {}
    for f in dataclasses.fields(options):
        if f.name in ("model", "grid_step_deg", "compliance", "drift", "grids"):
            continue
        v = getattr(options, f.name)
        if f.name == "budget":
            v = None if v is None else getattr(v, "name", str(v))
        elif isinstance(v, (tuple, list, np.ndarray)):
            v = [float(a) for a in v]
        elif not (v is None or isinstance(v, (bool, int, float, str))):
            v = str(v)
        out[f.name] = v
    return out


def cross_validate(chain, campaign, options, folds: int = 5, models=None, seed: int = 0) -> dict:
    """K-fold cross-validation by pose of candidate models of ``chain`` on ``campaign`` (io.serial_io.SerialCampaign)
    with the identify ``options`` (SerialIdentificationOptions; each candidate a ``dataclasses.replace`` of them).

    ``models``: None (:data:`DEFAULT_MODELS` that apply to the campaign), a comma text or a list of names or
    :class:`Candidate`; ``folds`` K >= 2 and at most the number of poses; ``seed``: the fold assignment's. Returns
    the CV document (module doc). Bad input (an unknown model, K out of range, drift without ``time_s``): one-line
    InputError."""
    fold = fold_of_rows(campaign, folds, seed)
    k = int(folds)
    cands = _candidates(chain, campaign, options, models)
    results = [_validate_one(chain, campaign, fold, k, c, o) for c, o in cands]
    name, reason = recommend(results)
    unique, _ = pose_keys(campaign)
    return {
        "format": FORMAT, "kind": "serial",
        "campaign": dict(file=campaign.source, kind=campaign.kind, readings=len(campaign), poses=len(unique),
                         sha256=campaign.digest().get("sha256"), time_s=campaign.time_s is not None),
        "folds": k, "seed": int(seed), "fold_assignment": ASSIGNMENT,
        "fold_poses": [int(len(pose_keys(campaign.subset(fold == f))[0])) for f in range(k)],
        "fold_readings": [int(np.sum(fold == f)) for f in range(k)],
        "metric": ("RMS of the held-out distance residuals (predicted - measured displacement), mm"
                   if campaign.kind == "distance" else
                   "RMS of the held-out 3D point errors |predicted - measured tracker point|, mm"),
        "rule": RULE, "models": results, "recommended": name, "reason": reason,
        "options": _options_dict(cands[0][1]),
    }


def table(cv: dict) -> str:
    """The validation as text: one line per model (mean +- std, se, per fold, refused, clamped), the choice."""
    lines = [f"{cv['folds']}-fold cross-validation by pose of {cv['campaign']['file']} ({cv['campaign']['poses']} "
             f"poses, {cv['campaign']['readings']} {cv['campaign']['kind']} readings, seed {cv['seed']}): "
             f"held-out RMS, mm",
             f"  {'model':24s}{'params':>7s}{'mean':>10s}{'std':>10s}{'se':>10s}  per fold"]
    for m in cv["models"]:
        folds = " ".join("refused" if v is None else f"{v:.4g}" for v in m["fold_rms_mm"])
        num = (lambda v: f"{v:10.4g}" if v is not None else f"{'-':>10s}")
        lines.append(f"  {m['name']:24s}{m['parameters'] if m['parameters'] is not None else '-':>7}"
                     f"{num(m['mean_rms_mm'])}{num(m['std_rms_mm'])}{num(m['se_rms_mm'])}  {folds}"
                     + (f"  ({m['clamped_readings']} held-out readings clamped)" if m["clamped_readings"] else ""))
        for r in m["refused"][:1]:
            lines.append(f"  {'':24s}refused in {m['n_refused']} fold(s), fold {r['fold']}: {short_reason(r['reason'])}")
    lines.append(f"recommended: {cv['recommended'] or 'none'} -- {cv['reason']}")
    lines.append(f"rule: {cv['rule']}")
    return "\n".join(lines)
