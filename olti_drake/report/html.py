"""The calibration report: one self-contained HTML page per result (``olti report``).

:func:`write_report` turns an identification result (SCARA ``olti-result/1``, paper 000, or
machine-tool ``olti-multilateration/1``, paper 001) -- optionally with its uncertainty file
(``olti uncertainty``), the campaign it came from and, for simulations, the truth -- into
``DIR/report.html``: header, parameter table with standard (k = 1) and expanded uncertainties, the
identified maps with error bars (000 Fig. 6), the ISO 230-2 style statistics per axis
(:mod:`olti_drake.report.iso230`), the uncertainty map of predicted positions (001 Fig. 14 style), residuals
per reflector and validation against the truth (000 Figs. 9-11). Figures are written as PNG files in
DIR *and* embedded as ``data:`` URIs; the page loads nothing from anywhere (no external CSS, JS,
fonts or images). All text is HTML-escaped. The output depends only on the inputs (no wall-clock
time unless ``date`` is passed).

Units: mm and degrees in the files; the page shows lengths in mm with uncertainties in µm, angles in
mdeg (and arc-seconds).
"""

import os
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import ISO230, ROBOT_RESULT as SCARA_FORMAT, UNCERTAINTY as UNCERTAINTY_FORMAT
from olti_drake.formats import VOLUMETRIC_RESULT as VOLUMETRIC_FORMAT
from olti_drake.io.csvio import read_json
from olti_drake.io.documents import read_result
from olti_drake.io.outputs import make_dir, preflight, write_json, write_text
from olti_drake.report import page as ui
from olti_drake.report.iso230 import (ARCSEC_PER_DEG, axis_statistics, map_statistics,
                     node_indices)

#: Every file the report may write into DIR (checked against the inputs before anything is written).
OUTPUT_NAMES = ("report.html", "iso230.json", "fig_maps.png", "fig_reversal.png", "fig_uncertainty_map.png",
                "fig_residuals.png", "fig_path_x200.png", "fig_error_vectors.png", "fig_targets.png",
                "fig_target_uncertainty.png", "fig_motions_X.png", "fig_motions_Y.png", "fig_motions_Z.png",
                "fig_volumetric_error.png", "fig_station_layout.png", "fig_motions_A.png", "fig_motions_B.png",
                "fig_motions_C.png")

# -- inputs ---------------------------------------------------------------------------------------------
def _budget_of(unc: Optional[dict], unc_path, default):
    """The budget named by an uncertainty file (its ``budget_file``), else ``default()``; (budget, note)."""
    from olti_drake.io.budget import load_budget

    name = (unc or {}).get("budget_file")
    if not name or str(name).startswith("built-in"):
        b = default()
        return b, f"budget {b.name!r}" + (" (as the uncertainty file)" if unc else " (default)")
    for cand in (name, os.path.join(os.path.dirname(os.fspath(unc_path)), name)):
        if os.path.isfile(cand):
            b = load_budget(cand)
            return b, f"budget {b.name!r} from {cand} (as the uncertainty file)"
    b = default()
    return b, (f"the uncertainty file's budget file {name} was not found; budget {b.name!r} used instead "
               f"(the map may differ from the uncertainty file's values)")


def _from_plain(obj):
    """truth.json's ``truth.robot`` (scenario.as_plain) back to the scenario dataclasses."""
    from olti_drake.model import errormap
    from olti_drake.sim import scenario

    allowed = {"Robot": scenario.Robot, "HarmonicDeviation": errormap.HarmonicDeviation,
               "Harmonic": errormap.Harmonic, "MapTable": scenario.MapTable, "NoDeviation": errormap.NoDeviation}
    if isinstance(obj, dict) and "_type" in obj:
        cls = allowed.get(obj["_type"])
        if cls is None:
            raise ValueError(f"unknown type {obj['_type']!r}")
        return cls(**{k: _from_plain(v) for k, v in obj.items() if k != "_type"})
    if isinstance(obj, list):
        return [_from_plain(v) for v in obj]
    return obj


def read_truth(path) -> dict:
    """A simulation truth (``truth.json`` of ``olti simulate`` / ``olti run`` on an emulated station).

    It is in the result format *plus* a ``truth`` object (the simulated robot, the search estimates,
    the seed). A result file has the same format but is an estimate, not a truth: validating a model
    against another estimate would print accuracies that mean nothing, so it is refused (one line,
    naming the file) before anything is written.
    """
    from olti_drake.io.result import load_result

    truth = load_result(path, outside="clamp")[3]  # a truth is a result-format file: the same schema check
    if not isinstance(truth.get("truth"), dict):
        raise InputError(f"{os.fspath(path)}: not a simulation truth (no 'truth' object: an identified result "
                         f"is not a truth; give the truth.json that olti simulate wrote)")
    return truth


def _truth_robot(truth: dict, truth_path):
    """(TrueRobot, nominal (L1, L2) mm, how) from a truth.json (result format, simulation truth)."""
    from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM
    from olti_drake.model.scara import TrueRobot
    from olti_drake.sim.scenario import MapTable

    plain = (truth.get("truth") or {}).get("robot")
    if plain is not None:
        try:
            r = _from_plain(plain)
            return r.true_robot(), (r.nominal_L1_mm, r.nominal_L2_mm), "the exact simulated deviation functions"
        except (TypeError, ValueError):
            pass
    try:
        L1, L2 = float(truth["L1_mm"]), float(truth["L2_mm"])
        if truth.get("model") == "dh":
            t20 = float(truth["theta20_deg"])
            dev = {"J2": MapTable([0.0], [t20], [t20])}
        else:
            dev = {a: MapTable(m["grid_deg"], m["forward_deg"], m.get("reverse_deg", m["forward_deg"]))
                   for a, m in truth["error_map"].items() if a in ("J1", "J2")}
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{os.fspath(truth_path)}: not a usable truth ({e})") from None
    return TrueRobot(L1, L2, dev), (PAPER_L1_MM, PAPER_L2_MM), "the truth's sampled maps (linear between nodes)"


# -- SCARA ------------------------------------------------------------------------------------------------
_SCARA_KEYS = ("L1_mm", "L2_mm", "theta20_deg", "error_map", "reflectors_mm", "dead_paths_mm")
_MACHINE_KEYS = ("targets_mm", "stations_mm", "dead_paths_mm")


def _parameter_rows(raw, model, std_src, k):
    rows = []

    def add(name, value, unit, u):
        if unit == "mm":
            rows.append((name, f"{value:.4f} mm", ui.num(None if u is None else 1e3 * u, ".2f"),
                         ui.num(None if u is None else 1e3 * k * u, ".2f"), "µm"))
        else:
            rows.append((name, f"{1e3 * value:.3f} mdeg", ui.num(None if u is None else 1e3 * u, ".3f"),
                         ui.num(None if u is None else 1e3 * k * u, ".3f"), "mdeg"))

    s = std_src or {}
    add("L1", raw["L1_mm"], "mm", s.get("L1_mm"))
    add("L2", raw["L2_mm"], "mm", s.get("L2_mm"))
    if not model.is_errormap:
        add("θ20", raw["theta20_deg"], "deg", s.get("theta20_deg"))
    for j, p in enumerate(raw.get("reflectors_mm", [])):
        for c, axis in enumerate("xy"):
            u = s.get("reflectors_mm")
            add(f"P{j}_{axis}", p[c], "mm", None if u is None else u[j][c])
    for j, d in enumerate(raw.get("dead_paths_mm", [])):
        u = s.get("dead_paths_mm")
        add(f"d0_{j}", d, "mm", None if u is None else u[j])
    return rows


def _branch(m: dict, block: str):
    """A map's ``<block>_deg`` values; a one-directional map (``forward_deg`` only) mirrors them as reverse."""
    return m.get(f"{block}_deg", m["forward_deg"])


def _scara_report(page, raw, result_path, unc, unc_path, campaign_path, truth, truth_path, k):
    from olti_drake.io.result import load_result

    model, P, d0, _ = load_result(result_path, outside="clamp", identified=True)
    std_src = unc if unc is not None else raw.get("uncertainty")
    if std_src is not None and unc is None:
        try:
            ui.check_uncertainty(std_src, raw, _SCARA_KEYS, result_path, result_path)
        except InputError:
            std_src = None
    std_label = ("the uncertainty file, method " + repr(unc.get("method", "?")) +
                 (f", budget {unc['budget']!r}" if unc.get("budget") else "")) if unc is not None else (
        "the result file (" + str(raw["uncertainty"].get("method", "identification")) + ")"
        if std_src is not None else None)
    bar_label = (f"{unc.get('method', '?')}" + (f", {unc['budget']}" if unc.get("budget") else "")
                 if unc is not None else "identification (result file)" if std_src is not None else None)

    # -- campaign: identifier, covariance, residuals -------------------------------------------------------
    ident = x = cov = data = None
    budget_note = campaign_note = ""
    if campaign_path is not None:
        from olti_drake.io.budget import default_budget
        from olti_drake.io.csvio import check_campaign_matches, load_campaign
        from olti_drake.estimation.identification import identifier_at_result
        from olti_drake.estimation.uncertainty import linear_covariance
        from olti_drake.model.budget import ReadingErrors

        data = load_campaign(campaign_path)
        campaign_note = check_campaign_matches(raw, data, result_path)
        ident, x = identifier_at_result(result_path, data)
        budget, budget_note = _budget_of(unc, unc_path, lambda: default_budget("scara"))
        cov = linear_covariance(ident, x, ReadingErrors(budget))

    # -- header ----------------------------------------------------------------------------------------------
    kind = raw["model"]
    page.add(f"<h1>Calibration report: SCARA, {ui.e('error-map model (000 Eq. 6-10)' if kind == 'errormap' else 'D-H model (000 Eq. 3-5)')}</h1>")
    info = [("result", os.fspath(result_path)), ("model", kind), ("gauge", raw.get("gauge", "—")),
            ("readings", raw.get("n_readings", "—")),
            ("residual RMS", f"{1e3 * float(raw['residual_rms_mm']):.2f} µm" if "residual_rms_mm" in raw else "—")]
    info += ui.fit_rows(raw)
    if raw.get("outliers"):
        info.append(("suspect readings", f"{len(raw['outliers'])} beyond the outlier threshold"))
    for note in raw.get("notes", []) + ([campaign_note] if campaign_note else []):
        info.append(("note", note))
    for warning in raw.get("warnings", []):
        info.append(("warning", warning))
    info += [("uncertainty file", os.fspath(unc_path) if unc_path else "— (the result's own uncertainties)"),
             ("campaign", os.fspath(campaign_path) if campaign_path else "—"),
             ("truth", os.fspath(truth_path) if truth_path else "—")]
    page.header_rows = info

    # -- parameters --------------------------------------------------------------------------------------------
    page.add("<h2>Identified parameters</h2>")
    page.source(None, columns={2: unc_path, 3: unc_path} if unc is not None else None)  # (u, U: the file's)
    if std_src is None:
        page.add(ui.p("No standard uncertainties available (neither an uncertainty file nor an 'uncertainty' object "
                    "in the result).", "note"))
    else:
        page.add(ui.p(f"Standard uncertainties u (k = 1) from {std_label}; expanded U = k·u with k = {k:g}"
                    + (" (the uncertainty file's 'expanded')." if unc is not None and "expanded" in unc else ".")))
    page.add(ui.table(["parameter", "value", "u (k = 1)", f"U (k = {k:g})", "unit of u, U"],
                    _parameter_rows(raw, model, std_src, k)))
    if kind == "errormap":
        page.add(ui.p("The map node values Δθ(θ*_i, ±1) and their uncertainties are in the per-axis node tables of the "
                    "ISO 230-2 section below."))

    truth_robot = truth_note = None
    if truth is not None:
        truth_robot, nominal, how = _truth_robot(truth, truth_path)
        truth_note = f"Truth: {how} from {os.fspath(truth_path)}."

    # -- maps with error bars ---------------------------------------------------------------------------------
    stats = truth_stats = None
    if kind == "errormap":
        import types

        from olti_drake.model.errormap import sample_map
        from olti_drake.report.figures import plot_identified_maps

        names, std_vec = [], []
        for axis, m in (("J1", model.map1), ("J2", model.map2)):
            for block in ("forward", "reverse"):
                names += [f"{axis}_{block}_deg[{i}]" for i in range(m.n_nodes)]
                std_vec += (list(np.ravel(_branch(std_src["error_map"][axis], block))) if std_src is not None
                            else [0.0] * m.n_nodes)
        std_vec = np.asarray(std_vec, dtype=float)
        page.add("<h2>Identified bidirectional angular positioning deviation (000 Fig. 6)</h2>")
        shown = types.SimpleNamespace(model=model, names=names, std=std_vec)
        page.figure(lambda p: plot_identified_maps(shown, truth_robot, p, std=std_vec,
                                                   method=bar_label),
                    "fig_maps.png", "Identified Δθ(θ*, ±1) of J1 and J2 with error bars u (k = 1)"
                    + (" and the simulated truth (J1 shifted by the gauge constant)" if truth_robot else "")
                    + ("" if std_src is not None else " -- no uncertainties available: bars are zero"))

        # -- ISO 230-2 ----------------------------------------------------------------------------------------
        node_cov, u_note = {}, ""
        if cov is not None:
            for axis, m in (("J1", model.map1), ("J2", model.map2)):
                idx = node_indices(ident.names, axis, m.n_nodes)
                C = cov[np.ix_(idx, idx)]
                sd = np.sqrt(np.maximum(np.diag(C), 0.0))
                if std_src is not None:  # the stated u, the linear method's correlations
                    s = np.concatenate([np.ravel(std_src["error_map"][axis]["forward_deg"]),
                                        np.ravel(_branch(std_src["error_map"][axis], "reverse"))])
                    with np.errstate(invalid="ignore", divide="ignore"):
                        Rm = np.where(np.outer(sd, sd) > 0, C / np.outer(sd, sd), 0.0)
                    np.fill_diagonal(Rm, 1.0)
                    C = Rm * np.outer(s, s)
                node_cov[axis] = C
            u_note = ("Uncertainties: node standard uncertainties from " + (std_label or "the linear method") +
                      ", with the correlations between node values from linear propagation (JCGM 100) through "
                      f"the identification on {os.fspath(campaign_path)} ({budget_note}); every statistic is "
                      "propagated to first order (u² = g C gᵀ), for the max/min statistics (B, E↑, E↓, E, M) as "
                      "the uncertainty of the arg-max/arg-min node combination at the estimate.")
            stats = map_statistics(model, cov=node_cov)
        elif std_src is not None:
            stats = map_statistics(model, std={a: np.concatenate([np.ravel(_branch(std_src["error_map"][a], b))
                                                                  for b in ("forward", "reverse")])
                                               for a in ("J1", "J2")})
            u_note = ("Uncertainties: node standard uncertainties from " + std_label + "; without the campaign "
                      "(--campaign) the correlations between node values are unknown and independence is assumed: "
                      "forward and reverse values of an identified map are usually strongly positively correlated, "
                      "so u(B_i), u(B), u(B̄) are then overstated and u(x̄_i) understated. For max/min statistics the "
                      "uncertainty is that of the arg-max/arg-min node combination (first order).")
        else:
            stats = map_statistics(model)
            u_note = "No uncertainties available: statistics without u."
        if truth_robot is not None:
            truth_stats = {a: axis_statistics(sample_map(truth_robot.deviation(a), m.grid_deg, a))
                           for a, m in (("J1", model.map1), ("J2", model.map2))}
        page.iso = stats
        ui.iso_section(page, stats, truth_stats, k, u_note,
                     None if truth_stats is None else truth_note + " Truth statistics from the truth's deviation at "
                     "the same nodes; (est − truth)/u beyond ±3 flags a disagreement (for an ambiguous max the "
                     "estimate is biased away from zero).")
        page.figure(lambda p: ui.plot_reversal(stats, truth_stats, k, p, "" if not stats["J1"].u else
                                             ("correlated (campaign)" if stats["J1"].correlated else "independent")),
                    "fig_reversal.png", f"Reversal values B_i with U (k = {k:g}) error bars, B̄ and B"
                    + (", truth ×" if truth_stats is not None else ""))

    # -- uncertainty map of predicted positions ------------------------------------------------------------
    page.add("<h2>Uncertainty of predicted positions (001 Fig. 14 style)</h2>")
    if kind != "errormap":
        page.add(ui.p("The predicted-position uncertainty map is drawn for error-map results (the workspace is the "
                    "identified map range); this is a D-H result.", "note"))
    elif cov is not None:
        from olti_drake.report.figures import plot_prediction_uncertainty_map, prediction_uncertainty_map

        pmap = prediction_uncertainty_map(ident, x, cov=cov)
        U = k * pmap["u_mm"]
        page.add(ui.p(f"Method: linear propagation (JCGM 100) of the full parameter covariance (correlations included) "
                    f"through the kinematic model, the covariance from the identification on "
                    f"{os.fspath(campaign_path)} with {budget_note}. Colour: U (k = {k:g}) = k·sqrt(u_x² + u_y²) "
                    f"on a {pmap['x_mm'][1] - pmap['x_mm'][0]:.3g} mm grid inside the map range; max "
                    f"{1e3 * np.nanmax(U):.2f} µm, mean {1e3 * np.nanmean(U):.2f} µm."
                    + (" The uncertainty file's own values came from Monte Carlo; this map is linear (the two agree "
                       "closely on this problem, README)." if unc is not None and unc.get("method") == "mc" else "")))
        page.figure(lambda p: plot_prediction_uncertainty_map(pmap, p, k, f"linear, {budget_note}"),
                    "fig_uncertainty_map.png", f"U (k = {k:g}) of predicted positions over the workspace, approach "
                                               f"directions +1 and −1")
    else:
        pe = (unc or {}).get("prediction_expanded_mm")
        msg = ("The map needs the covariance of the parameters (their correlations), which the uncertainty file does "
               "not carry: give the campaign (--campaign) to compute it by the linear method.")
        if pe:
            msg += (f" The uncertainty file's summary ({unc.get('method', '?')}): U (k = {pe.get('k', k):g}) max "
                    f"{1e3 * pe['max']:.2f} µm, mean {1e3 * pe['mean']:.2f} µm over {pe.get('points', '?')} points.")
        page.add(ui.p(msg, "note"))

    # -- residuals ------------------------------------------------------------------------------------------------
    page.add("<h2>Residuals</h2>")
    if ident is not None:
        page.source(campaign_path)
        r = ident.residuals(x)[0]
        grp = data.reflector
        rows = [(f"reflector {j}", int(np.sum(grp == j)), f"{1e3 * np.sqrt(np.mean(r[grp == j] ** 2)):.2f}",
                 f"{1e3 * np.max(np.abs(r[grp == j])):.2f}") for j in np.unique(grp)]
        rows.append(("all", len(r), f"{1e3 * np.sqrt(np.mean(r ** 2)):.2f}", f"{1e3 * np.max(np.abs(r)):.2f}"))
        page.add(ui.p(f"Model reading minus measured reading (Eq. (10) of 000) of every valid reading of "
                    f"{os.fspath(campaign_path)}, at the result's parameters."))
        page.add(ui.table(["readings of", "n", "RMS, µm", "max |r|, µm"], rows))
        page.figure(lambda p: ui.plot_residuals(np.arange(len(r)), r, grp, "reflector", p), "fig_residuals.png",
                    "Residuals per reflector vs reading index")
    else:
        page.add(ui.p("Give the campaign (--campaign) to plot the residuals per reflector.", "note"))

    # -- validation against the truth ------------------------------------------------------------------------------
    if truth_robot is not None:
        _validation_section(page, model, kind, truth_robot, nominal, data, truth_note, truth_path)


def _validation_section(page, model, kind, truth_robot, nominal, data, truth_note, truth_path=None):
    """000 §4.3 with the simulated tracker: the result's model (and the other model from the campaign)."""
    from olti_drake.report.figures import plot_error_vectors, plot_path_deviation
    from olti_drake.estimation.identification import IdentificationOptions, identify
    from olti_drake.report.validation import (PAPER_THETA1_RANGE, PAPER_THETA2_RANGE, STREAM_RANDOM_COMMANDS, STREAM_TRACKER, compare,
                             grid_paths, holding_map_ends, measure, outside_map, random_commands, x200_path)

    L1, L2 = nominal
    label = "error map" if kind == "errormap" else "D-H"
    models = {label: holding_map_ends(model)}
    if data is not None:
        other = "dh" if kind == "errormap" else "errormap"
        ident = identify(data, IdentificationOptions(model=other, nominal_L1_mm=L1, nominal_L2_mm=L2))
        models["D-H" if other == "dh" else "error map"] = holding_map_ends(ident.model)
    em = models.get("error map")
    if em is not None:
        r1, r2 = tuple(em.map1.grid_deg[[0, -1]]), tuple(em.map2.grid_deg[[0, -1]])
    else:
        r1, r2 = PAPER_THETA1_RANGE, PAPER_THETA2_RANGE
    sets = {"x200": x200_path(L1, L2), "grid": grid_paths(L1, L2, r1, r2),
            "random": random_commands(500, [0, STREAM_RANDOM_COMMANDS], r1, r2, L1, L2)}
    page.add("<h2>Validation on commands not used in the identification (000 §4.3, simulation)</h2>")
    page.source(truth_path)  # (the simulated truth's readings, compared with the result's models)
    page.add(ui.p("The simulated truth robot is measured by the simulated laser tracker (AT960-XR of 000 §4.3, seed 0) "
                "on the X = 200 mm path (Figs. 9-10), a grid of Cartesian paths (Fig. 11) and 500 random commands; "
                "each model's predictions are rotated about J1 onto the tracker readings (the unobservable gauge) "
                "before the 2D errors are taken. " + truth_note
                + (" The other model is identified from the campaign for comparison." if data is not None else "")))
    rows, results = [], {}
    for n, (key, cs) in enumerate(sets.items()):
        meas = measure(truth_robot, cs.commands, seed=[0, STREAM_TRACKER, n])
        cmp_ = compare(models, cs.commands, meas, cs.pass_dir)
        results[key] = (cs, meas, cmp_)
        outside = int(outside_map(em, cs.commands).sum()) if em is not None else 0
        for name, c in cmp_.items():
            rows.append((cs.name, name, len(cs), f"{1e3 * c['rms_mm']:.1f}", f"{1e3 * c['max_mm']:.1f}",
                         f"{1e3 * c['rotation_deg']:.2f}", outside))
    page.add(ui.table(["command set", "model", "points", "RMS, µm", "max, µm", "fitted rotation, mdeg",
                     "outside the map range"], rows, left=(0, 1)))
    if "D-H" in models and "error map" in models:
        cs, meas, c = results["x200"]
        page.figure(lambda p: plot_path_deviation(cs.xy_cmd_mm, cs.pass_dir, meas, c["D-H"]["predicted_mm"],
                                                  c["error map"]["predicted_mm"], p),
                    "fig_path_x200.png", "E_YY and E_XY along X = 200 mm: tracker vs models (000 Figs. 9-10)")
        gs, gmeas, gc = results["grid"]
        page.figure(lambda p: plot_error_vectors(gs.xy_cmd_mm, gs.pass_dir, gs.path_id, gmeas,
                                                 gc["error map"]["predicted_mm"], gc["D-H"]["predicted_mm"], p),
                    "fig_error_vectors.png", "Error vectors over the workspace (000 Fig. 11)")
    else:
        page.add(ui.p("Give the campaign (--campaign) to draw Figs. 9-11 (they compare the D-H and error-map models).",
                    "note"))


# -- machine tool (001) ------------------------------------------------------------------------------------
def _machine_report(page, raw, result_path, unc, unc_path, campaign_path, k):
    from olti_drake.estimation.multilateration import load_result

    load_result(result_path)  # checks the required keys
    std_src = unc if unc is not None else raw.get("uncertainty")
    if std_src is not None and unc is None:
        try:
            ui.check_uncertainty(std_src, raw, ("targets_mm",), result_path, result_path)
        except InputError:  # the result's own uncertainties are optional: without them, none are shown
            std_src = None
    D = int(np.shape(raw["targets_mm"])[1]) if np.ndim(raw["targets_mm"]) == 2 else 2  # 001's table or 3D
    T = np.asarray(raw["targets_mm"], dtype=float).reshape(-1, D)
    S = np.asarray(raw["stations_mm"], dtype=float).reshape(-1, D)
    axes = "xyz"[:D]
    L0 = np.asarray(raw["dead_paths_mm"], dtype=float).ravel()
    data, campaign_note = None, ""
    if campaign_path is not None:
        from olti_drake.estimation.multilateration import load_machine_campaign

        from olti_drake.io.csvio import check_campaign_matches

        data = load_machine_campaign(campaign_path)
        campaign_note = check_campaign_matches(raw, data, result_path)
        if data.n_targets != len(T) or data.n_stations != len(S):
            raise InputError(f"{os.fspath(result_path)}: {len(T)} targets and {len(S)} stations, but the campaign "
                             f"{os.fspath(campaign_path)} has {data.n_targets} and {data.n_stations}")
    cmd = (np.asarray(raw["commands_mm"], dtype=float).reshape(-1, D) if "commands_mm" in raw
           else data.commands_mm if data is not None else None)

    page.add("<h1>Calibration report: machine tool by self-calibrating multilateration (001 Eq. 2-6"
             + (", in 3D" if D == 3 else "") + ")</h1>")
    info = [("result", os.fspath(result_path)), ("format", raw["format"]), ("gauge", raw["gauge"]),
            ("readings", raw.get("n_readings", "—")),
            ("residual RMS", f"{1e3 * float(raw['residual_rms_mm']):.3f} µm" if "residual_rms_mm" in raw else "—"),
            ("targets / stations", f"{len(T)} / {len(S)}")]
    info += ui.fit_rows(raw)
    info += [("note", n) for n in ([campaign_note] if campaign_note else [])]
    info += [("warning", w) for w in raw.get("warnings", [])]
    info += [("uncertainty file", os.fspath(unc_path) if unc_path else "— (the result's own uncertainties)"),
             ("campaign", os.fspath(campaign_path) if campaign_path else "—")]
    page.header_rows = info

    uT = None if std_src is None else np.asarray(std_src["targets_mm"], dtype=float).reshape(-1, D)
    norm = lambda v: np.sqrt(np.sum(np.square(v), axis=-1))  # noqa: E731 (the 2-norm over x, y (, z))
    label = ("the uncertainty file, method " + repr(unc.get("method", "?"))) if unc is not None else (
        "the result file (" + str(std_src.get("method", "?")) + ")" if std_src is not None else None)
    page.add("<h2>Target positions</h2>")
    page.add(ui.p("Estimated target positions p_i in the result's gauge frame (" + str(raw["gauge"]) + "); deviation "
                "from the command p*_i in µm" + (f"; u (k = 1) from {label}, U = k·‖u‖ (x, y" + (", z" if D == 3 else "") + f") with "
                                                f"k = {k:g}." if label else "; no uncertainties available.")
                + ("" if cmd is not None else " No command positions (neither 'commands_mm' in the result nor "
                                              "--campaign): deviations not available.")))
    rows = []
    for i, p in enumerate(T):
        row = [i]
        if cmd is not None:
            d = 1e3 * (p - cmd[i])
            row += [f"{v:.3f}" for v in cmd[i]]
        row += [f"{v:.4f}" for v in p]
        if cmd is not None:
            row += [f"{v:+.2f}" for v in d] + [f"{norm(d):.2f}"]
        if uT is not None:
            row += [f"{1e3 * v:.2f}" for v in uT[i]] + [f"{1e3 * k * norm(uT[i]):.2f}"]
        rows.append(row)
    header = ["i"] + ([f"{a}*, mm" for a in axes] if cmd is not None else []) + [f"{a}, mm" for a in axes] + (
        [f"Δ{a}, µm" for a in axes] + ["|Δ|, µm"] if cmd is not None else []) + (
        [f"u_{a}, µm" for a in axes] + [f"U (k = {k:g}), µm"] if uT is not None else [])
    page.add(ui.table(header, rows, left=()))
    if cmd is not None:
        dev = 1e3 * norm(T - cmd)
        summary = f"Deviation from the commands: max {dev.max():.2f} µm, mean {dev.mean():.2f} µm"
        if uT is not None:
            U = 1e3 * k * norm(uT)
            summary += f"; U (k = {k:g}) of the 2-norm: max {U.max():.2f} µm, mean {U.mean():.2f} µm"
        page.add(ui.p(summary + "."))

    page.add("<h2>Stations and dead paths</h2>")
    uS = None if std_src is None or "stations_mm" not in std_src else np.asarray(std_src["stations_mm"]).reshape(-1, D)
    uL = None if std_src is None or "dead_paths_mm" not in std_src else np.ravel(std_src["dead_paths_mm"])
    rows = [[j] + [f"{v:.4f}" for v in S[j]] + [f"{L0[j]:.4f}"]
            + [ui.num(None if uS is None else 1e3 * uS[j, c], ".2f") for c in range(D)]
            + [ui.num(None if uL is None else 1e3 * uL[j], ".2f")] for j in range(len(S))]
    page.add(ui.table(["station"] + [f"{a}, mm" for a in axes] + ["dead path, mm"] + [f"u_{a}, µm" for a in axes]
                      + ["u dead path, µm"], rows))
    page.add(ui.p("ISO 230-2 statistics are given for the SCARA error map only: the multilateration estimates target "
                "positions, not an axis's positioning deviation at repeated approaches (compare the linear "
                "positioning errors of 001 Fig. 13).", "note"))

    if cmd is not None:
        from olti_drake.report.figures import plot_machine_targets, plot_target_uncertainty

        page.figure(lambda p: plot_machine_targets(cmd[:, :2], S[:, :2], T[:, :2], p,
                                                   stations_label="stations (identified)"),
                    "fig_targets.png", "Command and estimated target positions with the identified stations "
                    "(001 Fig. 10 style; no reference instrument is compared here)"
                    + ("; XY projection of the volume" if D == 3 else ""))
        if uT is not None:
            U = 1e3 * k * norm(uT)
            page.figure(lambda p: plot_target_uncertainty(cmd, U, p, k, label), "fig_target_uncertainty.png",
                        f"U (k = {k:g}) of the estimated target positions (001 Fig. 14)")
    page.add("<h2>Residuals</h2>")
    if data is not None:
        page.source(campaign_path)
        # 001 Eq. (3): the identified targets, stations and dead paths against every reading
        r = norm(T[data.target] - S[data.station]) - L0[data.station] - data.displacement_mm
        page.figure(lambda p: ui.plot_residuals(np.arange(len(r)), r, data.station, "station", p), "fig_residuals.png",
                    "Residuals per station vs reading index")
    else:
        page.add(ui.p("Give the campaign (--campaign) to plot the residuals per station.", "note"))


# -- the page ---------------------------------------------------------------------------------------------
def write_report(result_path, out_dir, uncertainty_path=None, campaign_path=None, truth_path=None,
                 date: Optional[str] = None, force: bool = False, iso9283_path=None, tolerances=None) -> list:
    """Write ``out_dir/report.html`` (self-contained) and its PNG figures; returns the written paths.

    Args:
        result_path: ``olti-result/1`` (SCARA, 000; N-joint robots), ``olti-multilateration/1`` (machine tool,
            001, 2D or 3D), ``olti-volumetric/1`` (the machine's 21 error motions:
            :mod:`olti_drake.report.volumetric_report`; no uncertainty file or truth) or ``olti-machine5/1``
            (a five-axis machine: :mod:`olti_drake.report.five_axis_report`; ``tolerances`` its acceptance
            thresholds, no truth).
        out_dir: output directory (created).
        uncertainty_path: ``olti uncertainty`` output for this result (``olti-uncertainty/1``); must have
            the result's keys and shapes. Default: the result's own ``uncertainty`` object.
        campaign_path: the campaign the result was identified from: enables the linear covariance
            (correlations for the ISO statistics, the predicted-position map) and the residual plot.
        truth_path: SCARA simulation truth (``truth.json`` of ``olti simulate``): truth overlays, truth
            ISO statistics and the validation of 000 §4.3.
        date: a date string to print in the header (default: the result's ``date`` key, if any; the
            report never reads the clock, so its bytes depend only on the inputs).
        force: replace report files already in ``out_dir`` (else refused; :mod:`olti_drake.io.outputs`).
        iso9283_path: a validation campaign of tracker points at repeated poses (N-joint robots): the ISO 9283
            pose accuracy and repeatability (:func:`olti_drake.report.serial_report.iso9283_section`);
            ``tolerances`` {characteristic: mm or deg} adds a verdict line per characteristic.

    Raises InputError / ValueError (one-line messages) for bad input, before writing anything
    when an output would overwrite an input or an existing file (without ``force``).
    """
    out_dir = os.fspath(out_dir)
    inputs = [os.fspath(p) for p in (result_path, uncertainty_path, campaign_path, truth_path, iso9283_path) if p]
    preflight([os.path.join(out_dir, name) for name in OUTPUT_NAMES], inputs, force=force, dirs=[out_dir],
              create_dirs=True)
    for p in inputs:
        if not os.path.isfile(p):
            raise InputError(f"{p}: " + ("is a directory, expected a file" if os.path.isdir(p) else "no such file"))
    kind, raw = read_result(result_path)  # (io.documents: the kind of any result file, old ones included)
    if (iso9283_path or tolerances) and kind not in ("serial", "machine5") or iso9283_path and kind == "machine5":
        raise InputError(f"{os.fspath(result_path)}: --iso9283 and --tolerance apply to robots from a model file "
                         f"(olti identify --robot), --tolerance also to five-axis results, not to a {kind} result")
    if tolerances and not iso9283_path and kind == "serial":
        raise InputError("--tolerance needs --iso9283 VALIDATION.csv (the campaign its characteristics come from)")
    if kind == "machine5":  # a five-axis machine: report/five_axis_report.py
        from olti_drake.report.five_axis_report import five_axis_page

        page = five_axis_page(raw, result_path, out_dir, uncertainty_path, campaign_path, truth_path, tolerances)
        return _write_page(page, raw, result_path, out_dir, date)
    if kind == "volumetric":  # the machine's 21 error motions: report/volumetric_report.py
        return _volumetric_page(raw, result_path, out_dir, uncertainty_path, campaign_path, truth_path, date)
    unc = read_json(uncertainty_path, UNCERTAINTY_FORMAT, "an uncertainty file") if uncertainty_path else None
    truth = None
    if truth_path and kind != "serial":
        if kind != "scara":
            raise InputError(f"{os.fspath(truth_path)}: --truth applies to SCARA results ({SCARA_FORMAT})")
        truth = read_truth(truth_path)
    if unc is not None and kind != "serial":
        ui.check_uncertainty(unc, raw, _SCARA_KEYS if kind == "scara" else _MACHINE_KEYS, uncertainty_path,
                             result_path)
    k = 2.0
    if unc is not None and isinstance(unc.get("expanded"), dict) and "k" in unc["expanded"]:
        k = float(unc["expanded"]["k"])
        if not (np.isfinite(k) and k > 0):
            raise InputError(f"{os.fspath(uncertainty_path)}: 'expanded.k' must be > 0, got {k:g}")

    page = ui.Page(out_dir, result_path)
    if kind == "serial":
        from olti_drake.report.serial_report import serial_report

        serial_report(page, raw, result_path, unc, uncertainty_path, campaign_path, truth_path, k, iso9283_path,
                      tolerances)
    elif kind == "scara":
        _scara_report(page, raw, result_path, unc, uncertainty_path, campaign_path, truth, truth_path, k)
    else:
        _machine_report(page, raw, result_path, unc, uncertainty_path, campaign_path, k)
    return _write_page(page, raw, result_path, out_dir, date)


def _volumetric_page(raw, result_path, out_dir, uncertainty_path, campaign_path, truth_path, date):
    """``olti-volumetric/1``: it carries its own uncertainty (covariance included) and has no simulation truth
    file, so --uncertainty and --truth are refused in one line; k = 2."""
    from olti_drake.report.volumetric_report import volumetric_report

    for given, option in ((uncertainty_path, "an uncertainty file"), (truth_path, "--truth")):
        if given:
            raise InputError(f"{os.fspath(given)}: {option} does not apply to a volumetric result ({VOLUMETRIC_FORMAT} "
                             f"carries its own uncertainty, covariance included); give the result and --campaign only")
    page = ui.Page(out_dir, result_path)
    volumetric_report(page, raw, result_path, campaign_path, 2.0)
    return _write_page(page, raw, result_path, out_dir, date)


def _write_page(page, raw, result_path, out_dir, date):
    """Write the filled ``page`` as report.html (and iso230.json for an error map); returns the written paths."""
    date = date if date is not None else raw.get("date")
    header = list(page.header_rows) + ([("date", date)] if date else [])
    page.source(None)  # (the header and the footer: the result's)
    page.add("<dl>" + "".join(f"<dt>{ui.e(a)}</dt><dd>{ui.e(b)}</dd>" for a, b in header) + "</dl>")
    page.add(ui.p(f"olti_drake report; units mm and degrees (uncertainties of lengths in µm, angles in mdeg; "
                  f"1 mdeg = {ARCSEC_PER_DEG / 1e3:g}″). Figures are embedded and written next to this page."))
    *sections, head, foot = page.parts
    body = [sections[0], head, page.legend()] + sections[1:] + [foot]
    doc = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
           f"<title>{ui.e('olti report: ' + os.path.basename(os.fspath(result_path)))}</title>"
           f"<style>{ui.CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    make_dir(out_dir)
    written = list(page.written)
    if page.iso is not None:
        path = os.path.join(out_dir, "iso230.json")
        write_json(path, {"format": ISO230, "result": os.fspath(result_path),
                          "what": "ISO 230-2 style systematic statistics of the identified error map, deg "
                                  "(olti_drake.report.iso230)", "k": 1,
                          "axes": {a: s.to_dict() for a, s in page.iso.items()}})
        written.append(path)
    path = os.path.join(out_dir, "report.html")
    write_text(path, doc)
    written.append(path)
    return written
