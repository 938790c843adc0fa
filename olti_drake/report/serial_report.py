"""The calibration report of an N-joint serial robot (``olti-result/1`` with a ``robot`` key).

One section per thing a calibration engineer checks (issue 13, item 8): the robot and the fit (model
file, tool frame, joints, gauge, residual RMS, iterations, condition number, notes); the geometric
parameters by name with u (k = 1) and U; what the campaign could not identify (``dropped``, with the
reason); the bidirectional joint maps of every joint with error bars (000 Fig. 6 per joint); the ISO
230-2 style statistics per joint (:mod:`olti_drake.report.iso230`, bidirectional maps only: a
one-directional map has no reversal); with the campaign, the residuals per station. A simulation truth
(``olti simulate``'s ``truth.json``) is overlaid on the maps, each joint's truth shifted by its mean
difference to the identified nodes (a map level trades with the joint-frame rotation about the axis
and, for the first joint, with the gauge).

Units: mm and degrees in the files; the page shows lengths with uncertainties in µm, angles in mdeg.
"""

import os
import types

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.serial_io import load_serial_result
from olti_drake.report import page as ui
from olti_drake.report.iso230 import axis_statistics

#: Keys of a serial result that hold identified values (the uncertainty object must match them).
_VALUE_SUFFIXES = ("_mm", "_deg")
_META = {"format", "kind", "model", "robot", "gauge", "residual_rms_mm", "n_readings", "uncertainty", "dropped", "iterations",
         "condition_number", "solver", "outliers", "converged", "warnings", "campaign", "notes", "held", "truth",
         "date", "station_labels", "drift_reference_h", "covariance", "smoothing", "priors"}


def value_keys(raw: dict) -> tuple:
    """The identified values of a serial result: location errors and offsets by name, the tool offset,
    the maps, and the stations + dead paths or the tracker frame."""
    return tuple(k for k in raw if k not in _META)


def _u(std_src, key, index=None):
    if std_src is None or key not in std_src:
        return None
    v = np.asarray(std_src[key], dtype=float)
    return float(v if index is None else v[index])


def _row(name, value, unit, u, k):
    """One parameter row: lengths in mm with u, U in µm; angles in mdeg."""
    if unit == "mm":
        return (name, f"{value:.4f} mm", ui.num(None if u is None else 1e3 * u, ".2f"),
                ui.num(None if u is None else 1e3 * k * u, ".2f"), "µm")
    return (name, f"{1e3 * value:.3f} mdeg", ui.num(None if u is None else 1e3 * u, ".3f"),
            ui.num(None if u is None else 1e3 * k * u, ".3f"), "mdeg")


def parameter_rows(raw: dict, std_src, k: float) -> list:
    """Rows of the parameter table: every scalar value by name, then tool offset, stations, dead paths."""
    rows = []
    for key in value_keys(raw):
        v = raw[key]
        if isinstance(v, (int, float)) and key.endswith(_VALUE_SUFFIXES):
            rows.append(_row(key, float(v), "mm" if key.endswith("_mm") else "deg", _u(std_src, key), k))
    for c, axis in enumerate("xyz"):
        rows.append(_row(f"tool offset {axis}", raw["tool_offset_mm"][c], "mm", _u(std_src, "tool_offset_mm", c), k))
    for j, P in enumerate(raw.get("stations_mm", [])):
        for c, axis in enumerate("xyz"):
            u = None if std_src is None or "stations_mm" not in std_src else float(std_src["stations_mm"][j][c])
            rows.append(_row(f"station {j} {axis}", P[c], "mm", u, k))
    for j, d in enumerate(raw.get("dead_paths_mm", [])):
        rows.append(_row(f"dead path {j}", d, "mm", _u(std_src, "dead_paths_mm", j), k))
    for j, v in enumerate(raw.get("drift_mm_per_h", [])):  # shown in µm/h
        u = _u(std_src, "drift_mm_per_h", j)
        rows.append((f"dead-path drift {j}", f"{1e3 * v:.3f} µm/h", ui.num(None if u is None else 1e3 * u, ".3f"),
                     ui.num(None if u is None else 1e3 * k * u, ".3f"), "µm/h"))
    frame = raw.get("tracker_frame")
    if isinstance(frame, dict):
        uf = (std_src or {}).get("tracker_frame") or {}
        for key, unit in (("translation_mm", "mm"), ("rotation_deg", "deg")):
            for c, axis in enumerate("xyz"):
                u = None if key not in uf else float(uf[key][c])
                rows.append(_row(f"tracker frame {key.split('_')[0]} {axis}", frame[key][c], unit, u, k))
    return rows


def _map_std(std_src, joint, block, n):
    try:
        return np.asarray(std_src["error_map"][joint][f"{block}_deg"], dtype=float).reshape(n)
    except (KeyError, TypeError, ValueError):
        return None


def plot_joint_maps(maps: dict, truth_maps, path, method: str = ""):
    """Identified Δθ_i(θ*_i, ±1) of every joint with k = 1 error bars (000 Fig. 6, one panel per joint), mdeg.

    ``maps``: {joint: (grid_deg, forward_deg, reverse_deg or None, u_forward or None, u_reverse or None)};
    ``truth_maps``: {joint: (grid_deg, forward_deg, reverse_deg)} on a fine grid, or None -- drawn shifted
    by the mean difference to the identified nodes (the level is not comparable: module docstring).
    """
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    fig, axes = ui.axis_panels(plt, len(maps), 3.8)
    for ax, (joint, (g, f, r, uf, ur)) in zip(axes, maps.items()):
        branches = [(f, uf, "tab:red", "+1")] + ([] if r is None else [(r, ur, "tab:blue", "−1")])
        for values, u, color, name in branches:
            ax.errorbar(g, 1e3 * values, yerr=None if u is None else 1e3 * u, fmt="o", color=color, ms=3, capsize=2,
                        label=f"identified, dir {name}")
        if truth_maps is not None and joint in truth_maps:
            tg, tf, tr = truth_maps[joint]
            ident_mean = np.mean(f if r is None else 0.5 * (f + r))
            at_nodes = np.interp(g, tg, tf if r is None else 0.5 * (tf + tr))
            shift = float(np.mean(at_nodes) - ident_mean)
            inside = (tg >= g[0]) & (tg <= g[-1])
            ax.plot(tg[inside], 1e3 * (tf[inside] - shift), color="tab:red", lw=1, alpha=0.5, label="truth +1 (shifted)")
            if r is not None:
                ax.plot(tg[inside], 1e3 * (tr[inside] - shift), color="tab:blue", lw=1, alpha=0.5, label="truth −1")
        ax.set(xlabel=ui.command_label(joint), ylabel="deviation, mdeg", title=f"{joint}: Δθ(θ*, dir)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
    fig.suptitle("Identified joint angular positioning deviation maps (000 Eq. (7), one panel per joint)"
                 + (f"; error bars u (k = 1): {method}" if method else ""), fontsize=9)
    return _save(fig, plt, path)


def _map_table(raw, std_src):
    """{joint: (grid, forward, reverse or None, u_forward, u_reverse)} of the result's maps."""
    out = {}
    for joint, m in (raw.get("error_map") or {}).items():
        g = np.asarray(m["grid_deg"], dtype=float)
        f = np.asarray(m["forward_deg"], dtype=float)
        r = np.asarray(m["reverse_deg"], dtype=float) if "reverse_deg" in m else None
        out[joint] = (g, f, r, _map_std(std_src, joint, "forward", g.size),
                      None if r is None else _map_std(std_src, joint, "reverse", g.size))
    return out


def _truth_maps(truth_path):
    truth = load_serial_result(truth_path, outside="clamp")
    maps = {}
    for joint, m in (truth.data.get("error_map") or {}).items():
        g = np.asarray(m["grid_deg"], dtype=float)
        f = np.asarray(m["forward_deg"], dtype=float)
        maps[joint] = (g, f, np.asarray(m.get("reverse_deg", m["forward_deg"]), dtype=float))
    return truth, maps


def _matching_campaign(raw, result, result_path, campaign_path):
    """The campaign ``--campaign`` names, refused (one line, both digests) unless it is the one the result was
    identified from (its ``campaign`` digest, as the SCARA and volumetric reports check; an older result without
    the digest: a note)."""
    from olti_drake.io.csvio import check_campaign_matches
    from olti_drake.io.serial_io import read_serial_campaign

    camp = read_serial_campaign(campaign_path, result.model.chain.n_joints)
    return camp, check_campaign_matches(raw, camp, result_path)


def _matching_truth(raw, result, result_path, truth_path):
    """The truth ``--truth`` names, refused (one line) unless it is a simulation truth (an identified result is
    an estimate) of the same robot: model file (digest, or the same file), tool frame and joints."""
    name = os.fspath(truth_path)
    truth, maps = _truth_maps(truth_path)
    if not truth.data.get("truth"):
        raise InputError(f"{name}: not a simulation truth (no 'truth': true -- an identified result is an estimate, "
                         f"not a truth); give the truth.json that olti simulate wrote")
    mine, theirs = raw.get("robot") or {}, truth.data.get("robot") or {}
    for key in ("tool_frame", "joints"):
        if mine.get(key) is not None and theirs.get(key) is not None and mine.get(key) != theirs.get(key):
            raise InputError(f"{name}: not the truth of {os.fspath(result_path)}'s robot: robot.{key} "
                             f"{theirs.get(key)!r}, the result's {mine.get(key)!r}")
    same = (mine["sha256"] == theirs["sha256"] if "sha256" in mine and "sha256" in theirs else
            os.path.realpath(result.robot_path) == os.path.realpath(truth.robot_path))
    if not same:
        raise InputError(f"{name}: not the truth of {os.fspath(result_path)}'s robot: its model file "
                         f"{truth.robot_path} is not the result's {result.robot_path}")
    return truth, maps


def _residuals(result, campaign_path, camp=None):
    """(residuals mm, station or group of each valid reading, label) of the identified model on the campaign."""
    from olti_drake.io.serial_io import read_serial_campaign

    if camp is None:
        camp = read_serial_campaign(campaign_path, result.model.chain.n_joints)
    p = result.model.positions(camp.commands, camp.dirs)
    if result.stations_mm is not None and camp.displacement_mm is not None:
        labels = np.unique(camp.station)  # the result's stations are the campaign's labels, ascending
        if len(labels) != len(result.stations_mm):
            raise InputError(f"{os.fspath(campaign_path)}: {len(labels)} stations, the result has "
                             f"{len(result.stations_mm)}: not the campaign of this result")
        j = np.searchsorted(labels, camp.station)
        pred = np.linalg.norm(p - result.stations_mm[j], axis=1) - result.dead_paths_mm[j]
        return camp.displacement_mm - pred, camp.station, "station"
    from olti_drake.model.frames import into_frame

    pred = into_frame(p, result.tracker_frame)
    return np.linalg.norm(camp.points_mm - pred, axis=1), np.zeros(len(pred), dtype=int), "tracker (distance)"


def serial_report(page, raw, result_path, unc, unc_path, campaign_path, truth_path, k, iso9283_path=None,
                  tolerances=None):
    """Fill ``page`` with the N-joint robot report (module docstring); sets ``page.iso`` per joint."""
    result = load_serial_result(result_path, outside="clamp", identified=True)
    # The inputs the report validates against are checked first (nothing is drawn from the wrong data).
    camp, campaign_note = _matching_campaign(raw, result, result_path, campaign_path) if campaign_path else (None, "")
    truth_maps = _matching_truth(raw, result, result_path, truth_path)[1] if truth_path is not None else None
    keys = value_keys(raw)
    std_src = unc if unc is not None else raw.get("uncertainty")
    if std_src is not None:
        try:
            ui.check_uncertainty(std_src, raw, keys, unc_path or result_path, result_path)
        except InputError:
            if unc is not None:
                raise
            std_src = None
    method = (unc or {}).get("method") or (raw.get("uncertainty") or {}).get("method", "")
    robot = raw["robot"]
    kind = raw["model"]
    what = "geometric + bidirectional joint maps (000 Eq. 6-10 per joint)" if kind == "errormap" else \
        "geometric model (joint location errors)"
    page.add(f"<h1>Calibration report: {ui.e(os.path.basename(robot['file']))}, {ui.e(what)}</h1>")
    info = [("result", os.fspath(result_path)), ("robot file", result.robot_path), ("tool frame", robot["tool_frame"]),
            ("joints", ", ".join(robot.get("joints", []))), ("model", kind), ("gauge", raw.get("gauge", "—")),
            ("readings", raw.get("n_readings", "—")),
            ("residual RMS", f"{1e3 * float(raw['residual_rms_mm']):.2f} µm" if "residual_rms_mm" in raw else "—")]
    info += ui.fit_rows(raw)
    if raw.get("outliers"):
        info.append(("suspect readings", f"{len(raw['outliers'])} beyond the outlier threshold"))
    info += [("note", n) for n in raw.get("notes", [])] + [("warning", w) for w in raw.get("warnings", [])]
    info += [("uncertainty file", os.fspath(unc_path) if unc_path else "— (the result's own uncertainties)"),
             ("campaign", os.fspath(campaign_path) if campaign_path else "—"),
             *([("note", campaign_note)] if campaign_note else []),
             ("truth", os.fspath(truth_path) if truth_path else "—")]
    page.header_rows = info

    page.add("<h2>Identified parameters</h2>")
    page.source(None, columns={2: unc_path, 3: unc_path} if unc is not None else None)  # (u, U: the file's)
    page.add(ui.p("Location errors of each joint frame relative to its parent (dx, dy, dz in mm; drx, dry, drz in "
                  "deg), the tool point's offset in the tool frame, and the measurement's own unknowns. "
                  + ("No standard uncertainties available." if std_src is None else
                     f"Standard uncertainties u (k = 1) from {method or 'the result'}; U = k·u, k = {k:g}.")))
    page.add(ui.table(["parameter", "value", "u (k = 1)", f"U (k = {k:g})", "unit of u, U"],
                      parameter_rows(raw, std_src, k)))
    dropped = raw.get("dropped") or []
    page.add("<h2>Identifiability</h2>")
    if dropped:
        page.add(ui.p(f"{len(dropped)} parameter(s) of the full model were not identified; each is held at its "
                      f"nominal (or start) value. The reason is the campaign's or the model's, as stated:"))
        page.add(ui.table(["parameter", "reason"], [(d.get("parameter", "?"), d.get("reason", ""))
                                                     for d in dropped if isinstance(d, dict)], left=(0, 1)))
    else:
        page.add(ui.p("Every parameter of the model was identified."))

    maps = _map_table(raw, std_src)
    if maps:
        page.add("<h2>Joint angular positioning deviation maps (000 Fig. 6, per joint)</h2>")
        page.figure(lambda path: plot_joint_maps(maps, truth_maps, path, method), "fig_maps.png",
                    "Identified Δθ(θ*, ±1) of every joint with error bars u (k = 1)"
                    + (", truth shifted per joint by its mean difference" if truth_maps else ""))
        stats = {}
        for joint, (g, f, r, uf, ur) in maps.items():
            if r is None:
                continue
            std = None if uf is None or ur is None else (uf, ur)
            stats[joint] = axis_statistics(types.SimpleNamespace(grid_deg=g, forward_deg=f, reverse_deg=r),
                                           std=std, axis=joint)
        one_way = [j for j, m in maps.items() if m[2] is None]
        if one_way:
            page.add(ui.p(f"One-directional map(s) ({', '.join(one_way)}): the campaign has no direction columns, "
                          f"so no reversal (backlash) can be identified and no ISO 230-2 reversal statistics are "
                          f"given.", "note"))
        if stats:
            page.iso = stats
            ui.iso_section(page, stats, None, k, "u from the node uncertainties taken as independent (the "
                                                 "result's per-node u); correlations not included.", None)
            page.figure(lambda path: ui.plot_reversal(stats, None, k, path, method), "fig_reversal.png",
                        "Reversal values B_i per joint with U")
    if campaign_path is not None:
        r, group, label = _residuals(result, campaign_path, camp)
        page.add("<h2>Residuals</h2>")
        page.source(campaign_path)
        page.add(ui.p(f"Reading minus the identified model's prediction for every valid reading of the campaign "
                      f"(a point campaign: the distance between the measured and the predicted point), RMS {1e3 * np.sqrt(np.mean(r ** 2)):.2f} µm."))
        page.figure(lambda path: ui.plot_residuals(np.arange(len(r)), r, group, label, path), "fig_residuals.png",
                    f"Residuals per {label}")
    if iso9283_path is not None:
        iso9283_section(page, result, iso9283_path, tolerances)


def iso9283_section(page, result, validation_path, tolerances=None) -> list:
    """ISO 9283 pose accuracy and repeatability (:mod:`olti_drake.report.iso9283`) from a validation campaign of
    tracker points with repeated cycles (formats.md's point campaign: the joint commands, optional directions,
    x_mm, y_mm, z_mm): each distinct command row is a pose (P1, P2, ... in order of appearance), its rows the
    cycles. The attained points go into the base frame by the result's tracker frame (a result identified from
    tracker points; otherwise they are taken as given in the base frame, and the page says so). Two commanded
    poses: the **nominal** kinematics (the robot file, with the identified tool point: what an uncalibrated
    controller commands) and the **identified** model's prediction (what a compensation by this result would
    leave). RP is the same for both. Returns the verdict lines (``tolerances``: {characteristic: mm/deg})."""
    from olti_drake.io.serial_io import read_serial_campaign
    from olti_drake.model.frames import out_of_frame as tracker_to_base
    from olti_drake.report.iso9283 import STANDARD_CYCLES, pose_characteristics, verdicts

    model = result.model
    camp = read_serial_campaign(validation_path, model.chain.n_joints)
    if camp.kind != "point":
        raise InputError(f"{os.fspath(validation_path)}: --iso9283 needs a point campaign (x_mm, y_mm, z_mm measured "
                         f"by a tracker at repeated poses), not a {camp.kind} campaign")
    key = np.round(camp.commands, 6) if camp.dirs is None else np.round(np.hstack([camp.commands, camp.dirs]), 6)
    _, first, pose = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # pose labels 1, 2, ... by first appearance
    pose = order[pose.ravel()] + 1
    frame = result.tracker_frame
    attained = camp.points_mm if frame is None else tracker_to_base(camp.points_mm, frame)
    x = result.x
    nominal = np.zeros_like(x)
    tool = [i for i, n in enumerate(model.names) if n in ("tool_x_mm", "tool_y_mm", "tool_z_mm")]
    nominal[tool] = x[tool]
    where = os.fspath(validation_path)
    by_nominal = pose_characteristics(pose, model.positions(camp.commands, camp.dirs, nominal), attained,
                                      camp.line, where)
    by_model = pose_characteristics(pose, model.positions(camp.commands, camp.dirs, x), attained, camp.line, where)
    page.add("<h2>ISO 9283 pose accuracy and repeatability</h2>")
    page.source(validation_path)
    digest = page.digest(validation_path)
    n = min(c.cycles for c in by_model)
    page.add(ui.p(f"From {ui.e(where)} (sha256 {digest[:16]}…): {len(by_model)} poses, {n}–"
                  f"{max(c.cycles for c in by_model)} cycles each"
                  + (f" (fewer than the standard's {STANDARD_CYCLES})" if n < STANDARD_CYCLES else "")
                  + ("; attained points taken into the base frame by the result's tracker frame" if frame is not None
                     else "; the result holds no tracker frame: the attained points are taken as given, in the "
                          "base frame") + ". AP_P = ‖mean attained − commanded‖ (7.2.1), RP_l = l̄ + 3 S_l "
                  "(7.2.2); commanded by the nominal kinematics (robot file, identified tool point) and by the "
                  "identified model. µm."))
    rows = [(f"P{a.pose}", a.cycles, f"{1e3 * a.AP_P:.1f}", f"{1e3 * b.AP_P:.1f}", f"{1e3 * b.RP_l:.1f}")
            for a, b in zip(by_nominal, by_model)]
    page.add(ui.table(["pose", "cycles", "AP_P nominal (µm)", "AP_P identified (µm)", "RP_l (µm)"], rows))
    lines = []
    if tolerances:
        lines = [f"nominal: {t}" for t in verdicts(by_nominal, tolerances)] + \
                [f"identified: {t}" for t in verdicts(by_model, tolerances)]
        page.add(ui.table(["verdict (ISO 9283)"], [(t,) for t in lines], left=(0,)))
    return lines


def plot_workspace_uncertainty(points_mm, expanded_um, path, k: float = 2.0, method: str = "", most: int = 4):
    """The predicted tool point's expanded uncertainty over the workspace as slices of the volume (z bands,
    001 Fig. 14 in 3D): one XY panel per band of equal count, one colour scale; µm."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    p, U = np.asarray(points_mm, float), np.asarray(expanded_um, float)
    n = min(most, max(1, len(p) // 20))
    edges = np.quantile(p[:, 2], np.linspace(0, 1, n + 1))
    fig, axes = plt.subplots(1, n, figsize=(5.0 * n + 1.5, 4.8), squeeze=False)
    norm = plt.Normalize(U.min(), U.max())
    for i, ax in enumerate(axes[0]):
        at = (p[:, 2] >= edges[i]) & ((p[:, 2] <= edges[i + 1]) if i == n - 1 else (p[:, 2] < edges[i + 1]))
        sc = ax.scatter(p[at, 0], p[at, 1], c=U[at], norm=norm, s=22, cmap="jet", edgecolors="none")
        ax.set(xlabel="x, mm", ylabel="y, mm", title=f"z {edges[i]:.0f} … {edges[i + 1]:.0f} mm ({int(at.sum())} poses)")
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
    fig.colorbar(sc, ax=axes[0][-1], label=f"U (k = {k:g}) = k·sqrt(u_x² + u_y² + u_z²), µm")
    fig.suptitle(f"Predicted tool-point uncertainty over the workspace: max {U.max():.1f} µm, mean {U.mean():.1f} µm"
                 + (f" -- {method}" if method else ""), fontsize=10)
    return _save(fig, plt, path)
