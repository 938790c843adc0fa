"""The calibration report of a machine tool's volumetric model (``olti-volumetric/1``; issue 15 item 5).

One section per thing a calibration engineer checks (``olti report R.json [--campaign C.csv]``): the fit
(topology, travel, representation, readings, residual RMS, solver); the 18 error motions of the X, Y and
Z axes in ISO 230-1 names with their uncertainty bands U = k·u (one figure per axis, six panels); the
three squareness errors, the tool offsets, the stations and dead paths with u and U; what was held at 0
and why (the observability of the campaign); the gauge; the **volumetric error before and after
compensation** in ISO 230-1 terms over a grid of the travel (:func:`volumetric_figures`); the station
layout in 3D (XY and XZ projections of the travel box); with the campaign, the residuals per station
(001 Eq. (3) on the model).

Units: mm and µrad in the file; the page shows linear motions and errors in µm, angles in µrad.
"""

import os

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.volumetric_io import load_volumetric_result
from olti_drake.model.volumetric3d import ALL_MOTIONS, AXES, SQUARENESS, error_grid, motion_names, motion_role
from olti_drake.report import page as ui

#: Every figure the volumetric page may write (html.OUTPUT_NAMES includes them).
FIGURES = ("fig_motions_X.png", "fig_motions_Y.png", "fig_motions_Z.png", "fig_volumetric_error.png",
           "fig_station_layout.png")
#: Grid intervals along the longest travel for the volumetric figures (the pitch is its travel / this).
GRID_INTERVALS = 8


def _shown(v, unit):
    """A motion value in the page's unit: mm -> µm, µrad as is."""
    return 1e3 * np.asarray(v, float) if unit == "mm" else np.asarray(v, float)


def _page_unit(unit):
    return "µm" if unit == "mm" else "µrad"


def grid_pitch_mm(config) -> float:
    """Pitch of the volumetric grid: the longest travel / ``GRID_INTERVALS`` (mm)."""
    return max(hi - lo for lo, hi in config.travel_mm.values()) / GRID_INTERVALS


def volumetric_figures(res, k: float = 2.0, pitch_mm=None) -> dict:
    """The volumetric accuracy of the identified machine over a grid of its travel, per tool (ISO 230-1 terms).

    Before compensation: the positioning-error vectors e = actual − command − tool offset of the model
    (:func:`~olti_drake.model.volumetric3d.error_grid`, mm) -- max and mean |e|, and per direction the range
    of the component (E_VX, E_VY, E_VZ: the largest minus the smallest x, y, z deviation over the volume).
    After compensation the commands put the model's tool point on the wanted point, so what remains is the
    model's error: its uncertainty, U = k·sqrt(u_x² + u_y² + u_z²) of the predicted point (linear, the
    result's covariance, JCGM 100) -- max and mean. Returns {tool: {...}} with the grids (mm)."""
    cfg = res.model.config
    pitch = grid_pitch_mm(cfg) if pitch_mm is None else float(pitch_mm)
    out = {}
    for tool in range(len(cfg.tools)):
        g = error_grid(res.motions, cfg, pitch, tool)
        c = np.column_stack([g["x_cmd_mm"], g["y_cmd_mm"], g["z_cmd_mm"]])
        e = np.column_stack([g["dx_mm"], g["dy_mm"], g["dz_mm"]])
        u = res.position_std(c, np.full(len(c), tool))
        norm = np.linalg.norm(e, axis=1)
        U = k * np.linalg.norm(u, axis=1)
        out[tool] = {"commands_mm": c, "error_mm": e, "u_mm": u, "pitch_mm": pitch, "points": len(c),
                     "max_error_mm": float(norm.max()), "mean_error_mm": float(norm.mean()),
                     "range_mm": np.ptp(e, axis=0), "max_U_mm": float(U.max()), "mean_U_mm": float(U.mean()),
                     "U_mm": U, "error_norm_mm": norm}
    return out


# -- figures ------------------------------------------------------------------------------------------------
def plot_axis_motions(doc: dict, axis: str, k: float, path):
    """The six error motions of one axis (value and the U = k·u band, µm or µrad) at the stated positions."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    fig, axes = ui.axis_panels(plt, 6, 3.2)
    unc = doc["uncertainty"]["error_motions"]
    for ax, name in zip(axes, motion_names(axis)):
        m = doc["error_motions"][name]
        q, unit = np.asarray(m["positions_mm"], float), m["unit"]
        v, U = _shown(m["values"], unit), k * _shown(unc[name], unit)
        held = not m.get("identified", True)
        ax.fill_between(q, v - U, v + U, color="tab:blue", alpha=0.25, label=f"U (k = {k:g})")
        ax.plot(q, v, color="0.5" if held else "tab:blue", lw=1.5, ls="--" if held else "-",
                label="held at 0 (not separable)" if held else "identified")
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel=f"{axis} command, mm", ylabel=f"{name}, {_page_unit(unit)}",
               title=f"{name}: {motion_role(name)}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Error motions of the {axis} axis (ISO 230-1), with U (k = {k:g}) bands", fontsize=10)
    return _save(fig, plt, path)


def plot_volumetric_error(fig_data: dict, k: float, path, most: int = 3):
    """Tool 0: the positioning-error vectors (XY arrows, colour |e|) and U after compensation, at a few Z levels."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    c, e, U = fig_data["commands_mm"], fig_data["error_mm"], fig_data["U_mm"]
    levels = np.unique(c[:, 2])
    shown = levels[np.unique(np.round(np.linspace(0, len(levels) - 1, min(most, len(levels)))).astype(int))]
    fig, axes = plt.subplots(2, len(shown), figsize=(5.2 * len(shown), 9.0), squeeze=False)
    norm_um, U_um = 1e3 * fig_data["error_norm_mm"], 1e3 * U
    span = np.ptp(c[:, :2], axis=0).max() or 1.0
    scale = fig_data["max_error_mm"] / (0.08 * span) if fig_data["max_error_mm"] > 0 else 1.0
    for col, z in enumerate(shown):
        s = c[:, 2] == z
        ax = axes[0, col]
        q = ax.quiver(c[s, 0], c[s, 1], e[s, 0], e[s, 1], norm_um[s], angles="xy", scale_units="xy", scale=scale,
                      cmap="viridis", clim=(0, norm_um.max()))
        ax.set(title=f"z = {z:g} mm: error vectors (XY), colour |e|", xlabel="X command, mm", ylabel="Y command, mm")
        ax.set_aspect("equal")
        ax.margins(0.1)
        fig.colorbar(q, ax=ax, label="|e| before compensation, µm")
        ax = axes[1, col]
        sc = ax.scatter(c[s, 0], c[s, 1], c=U_um[s], s=90, marker="s", cmap="jet", vmin=0, vmax=U_um.max())
        ax.set(title=f"z = {z:g} mm: after compensation, U (k = {k:g})", xlabel="X command, mm",
               ylabel="Y command, mm")
        ax.set_aspect("equal")
        ax.margins(0.1)
        fig.colorbar(sc, ax=ax, label=f"U (k = {k:g}) of the predicted point, µm")
    fig.suptitle(f"Volumetric error of tool 0: before compensation max |e| {1e3 * fig_data['max_error_mm']:.1f} µm; "
                 f"after, U (k = {k:g}) max {1e3 * fig_data['max_U_mm']:.2f} µm", fontsize=10)
    return _save(fig, plt, path)


def plot_station_layout(config, stations_mm, path):
    """XY and XZ projections of the travel box (commands, mm) and the identified stations."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    S = np.asarray(stations_mm, float)
    lo = np.array([config.travel_mm[a][0] for a in AXES])
    hi = np.array([config.travel_mm[a][1] for a in AXES])
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.4))
    for ax, (a, b) in zip(axes, ((0, 1), (0, 2))):
        ax.add_patch(plt.Rectangle((lo[a], lo[b]), hi[a] - lo[a], hi[b] - lo[b], fill=False, color="tab:blue",
                                   lw=1.5, label="travel (commands)"))
        ax.plot(S[:, a], S[:, b], "^", color="tab:red", ms=10, label="stations (identified)")
        for j, P in enumerate(S):
            ax.annotate(f" {j}", (P[a], P[b]), fontsize=9)
        ax.set(xlabel=f"{'xyz'[a]}, mm", ylabel=f"{'xyz'[b]}, mm", title=f"{'XYZ'[a]}{'XYZ'[b]} projection")
        ax.set_aspect("equal")
        ax.margins(0.15)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Station layout in 3D (the gauge frame: origin at tool 0's point at the travel start)", fontsize=10)
    return _save(fig, plt, path)


# -- the page ---------------------------------------------------------------------------------------------
def _header(page, res, raw, result_path, campaign_path, campaign_note):
    cfg = res.model.config
    page.add("<h1>Calibration report: machine tool, volumetric model (21 ISO 230-1 error motions, 001 in 3D)</h1>")
    info = [("result", os.fspath(result_path)), ("format", raw["format"]),
            ("topology", "work " + ("–".join(cfg.work_chain) or "—") + ", tool " + "–".join(cfg.tool_chain)),
            ("travel", ", ".join(f"{a} {lo:g} … {hi:g} mm" for a, (lo, hi) in cfg.travel_mm.items())),
            ("representation", f"{raw['representation']['basis']}, knots ≤ {cfg.knot_spacing_mm:g} mm"),
            ("parameters", len(res.model.parameter_names())),
            ("readings", raw.get("n_readings", "—")),
            ("residual RMS", f"{1e3 * float(raw['residual_rms_mm']):.3f} µm" if "residual_rms_mm" in raw else "—"),
            ("uncertainty", str(raw["uncertainty"].get("method", "—")))]
    info += ui.fit_rows(raw)
    info += [("note", n) for n in raw.get("notes", []) + ([campaign_note] if campaign_note else [])]
    info += [("warning", w) for w in raw.get("warnings", [])]
    info.append(("campaign", os.fspath(campaign_path) if campaign_path else "—"))
    page.header_rows = info


def _motions_section(page, raw, k):
    page.add("<h2>Error motions (ISO 230-1)</h2>")
    page.add(ui.p(f"Each motion is a function of its axis' command, identified at the stated positions every "
                  f"{raw['pitch_mm']:g} mm; u (k = 1) by {raw['uncertainty'].get('method', 'linear propagation')}; "
                  f"bands U = k·u with k = {k:g}. Linear motions in µm, angular motions in µrad. Sign conventions: "
                  f"tool relative to workpiece ({raw.get('conventions', 'docs/machine_3d.md')})."))
    unc = raw["uncertainty"]["error_motions"]
    rows = []
    for name in ALL_MOTIONS:
        m = raw["error_motions"][name]
        unit = m["unit"]
        v, u = _shown(m["values"], unit), _shown(unc[name], unit)
        rows.append((name, m["axis"], motion_role(name), _page_unit(unit), f"{v.min():+.3f}", f"{v.max():+.3f}",
                     f"{k * u.max():.3f}", m["fixed"], "yes" if m.get("identified", True) else "held at 0"))
    page.add(ui.table(["motion", "axis", "role", "unit", "min", "max", f"max U (k = {k:g})", "fixed (gauge)",
                       "identified"], rows, left=(0, 1, 2, 3, 7, 8)))
    for axis in AXES:
        page.figure(lambda p, a=axis: plot_axis_motions(raw, a, k, p), f"fig_motions_{axis}.png",
                    f"The six error motions of the {axis} axis with U (k = {k:g}) bands")


def _squareness_tools_stations(page, res, raw, k):
    unc = raw["uncertainty"]
    page.add("<h2>Squareness</h2>")
    rows = [(s, f"{raw['squareness_urad'][s]:+.3f}", f"{unc['squareness_urad'][s]:.3f}",
             f"{k * unc['squareness_urad'][s]:.3f}") for s in SQUARENESS]
    page.add(ui.table(["squareness", "value, µrad", "u (k = 1), µrad", f"U (k = {k:g}), µrad"], rows))
    page.add(ui.p("E_C0Y: Y to X; E_B0Z: Z to X; E_A0Z: Z to Y (right-hand rotations of the axis' reference "
                  "straight line, ISO 230-1)."))

    page.add("<h2>Tool offsets</h2>")
    T, uT = np.asarray(raw["tool_offsets_mm"], float), np.asarray(unc["tool_offsets_mm"], float)
    err = np.asarray(raw["tool_offset_errors_mm"], float)
    rows = [[m] + [f"{v:.4f}" for v in T[m]] + [f"{1e3 * v:+.2f}" for v in err[m]]
            + [f"{1e3 * k * v:.2f}" for v in uT[m]] + ["given (the origin)" if m == 0 else
                                                      "identified" if raw.get("tool_offsets_identified") else "given"]
            for m in range(len(T))]
    page.add(ui.table(["tool", "x, mm", "y, mm", "z, mm", "error x, µm", "error y, µm", "error z, µm",
                       f"U_x (k = {k:g}), µm", "U_y, µm", "U_z, µm", "status"], rows, left=(10,)))

    page.add("<h2>Stations and dead paths</h2>")
    S, L0 = np.asarray(raw["stations_mm"], float), np.asarray(raw["dead_paths_mm"], float)
    uS, uL = np.asarray(unc["stations_mm"], float), np.asarray(unc["dead_paths_mm"], float)
    rows = [[j] + [f"{v:.4f}" for v in S[j]] + [f"{L0[j]:.4f}"] + [f"{1e3 * k * v:.2f}" for v in uS[j]]
            + [f"{1e3 * k * uL[j]:.2f}"] for j in range(len(S))]
    page.add(ui.table(["station", "x, mm", "y, mm", "z, mm", "dead path, mm", f"U_x (k = {k:g}), µm", "U_y, µm",
                       "U_z, µm", "U dead path, µm"], rows))
    page.figure(lambda p: plot_station_layout(res.model.config, S, p), "fig_station_layout.png",
                "Station layout: XY and XZ projections of the travel box and the stations")


def _observability_section(page, raw):
    page.add("<h2>Observability and gauge</h2>")
    page.add(ui.p("Observability of the campaign: " + str(raw.get("observability", "—"))))
    held = raw.get("held_motions") or {}
    if held:
        page.add(ui.p("Held at 0 (the campaign cannot separate them; the motions they trade with carry their "
                      "effect at the measured tool points):", "note"))
        page.add(ui.table(["motion", "why"], sorted(held.items()), left=(0, 1)))
    else:
        page.add(ui.p("Every error motion was separable: none held at 0."))
    page.add(ui.p("Gauge: " + str(raw["gauge"])))
    page.add(ui.table(["gauge condition (not an unknown)"], [(c,) for c in raw.get("gauge_conditions", [])],
                      left=(0,)))


def _volumetric_section(page, res, k):
    figs = volumetric_figures(res, k)
    page.add("<h2>Volumetric error before and after compensation (ISO 230-1)</h2>")
    f0 = figs[0]
    page.add(ui.p(f"Positioning-error vectors e = actual − command − tool offset of the identified model on a "
                  f"{f0['pitch_mm']:.4g} mm grid of the travel ({f0['points']} points per tool). Before compensation: "
                  f"max and mean |e| (the volumetric accuracy of the machine as identified) and E_VX, E_VY, E_VZ, the "
                  f"range (largest − smallest) of the x, y, z deviation over the volume. After compensation the "
                  f"commands put the model's tool point on the wanted point: what remains is the model's own "
                  f"error, U (k = {k:g}) = k·sqrt(u_x² + u_y² + u_z²) of the predicted point (linear propagation of "
                  f"the result's covariance, JCGM 100)."))
    rows = []
    for tool, f in figs.items():
        rows.append((tool, f"{1e3 * f['max_error_mm']:.2f}", f"{1e3 * f['mean_error_mm']:.2f}",
                     *(f"{1e3 * v:.2f}" for v in f["range_mm"]), f"{1e3 * f['max_U_mm']:.3f}",
                     f"{1e3 * f['mean_U_mm']:.3f}"))
    page.add(ui.table(["tool", "before: max |e|, µm", "mean |e|, µm", "E_VX, µm", "E_VY, µm", "E_VZ, µm",
                       f"after: max U (k = {k:g}), µm", "mean U, µm"], rows))
    page.figure(lambda p: plot_volumetric_error(f0, k, p), "fig_volumetric_error.png",
                f"Tool 0: error vectors before compensation (top) and U (k = {k:g}) after (bottom), Z slices")


def _residual_section(page, res, raw, data, campaign_path):
    page.add("<h2>Residuals</h2>")
    if data is None:
        page.add(ui.p("Give the campaign (--campaign) to plot the residuals per station.", "note"))
        return
    page.source(campaign_path)
    S, L0 = np.asarray(raw["stations_mm"], float), np.asarray(raw["dead_paths_mm"], float)
    p = res.model.positions(data.commands_mm, data.tool, res.params)
    r = np.linalg.norm(p[data.target] - S[data.station], axis=1) - L0[data.station] - data.displacement_mm
    rows = [(f"station {j}", int(np.sum(data.station == j)), f"{1e3 * np.sqrt(np.mean(r[data.station == j] ** 2)):.3f}",
             f"{1e3 * np.max(np.abs(r[data.station == j])):.3f}") for j in np.unique(data.station)]
    rows.append(("all", len(r), f"{1e3 * np.sqrt(np.mean(r ** 2)):.3f}", f"{1e3 * np.max(np.abs(r)):.3f}"))
    page.add(ui.p(f"Model reading minus measured reading (001 Eq. (3) on the volumetric model) of every valid "
                  f"reading of {os.fspath(campaign_path)}, at the result's parameters."))
    page.add(ui.table(["readings of", "n", "RMS, µm", "max |r|, µm"], rows))
    page.figure(lambda path: ui.plot_residuals(np.arange(len(r)), r, data.station, "station", path),
                "fig_residuals.png", "Residuals per station vs reading index")


def volumetric_report(page, raw, result_path, campaign_path, k):
    """Fill ``page`` with the volumetric result's report (module docstring); one-line errors for bad input."""
    res = load_volumetric_result(result_path)
    data, note = None, ""
    if campaign_path is not None:
        from olti_drake.estimation.multilateration import load_machine_campaign
        from olti_drake.estimation.volumetric import volumetric_campaign
        from olti_drake.io.csvio import check_campaign_matches

        data = volumetric_campaign(load_machine_campaign(campaign_path))
        note = check_campaign_matches(raw, data, result_path)
        if data.n_stations != len(raw["stations_mm"]) or data.n_tools > len(res.model.config.tools):
            raise InputError(f"{os.fspath(campaign_path)}: {data.n_stations} stations and {data.n_tools} tools, but "
                             f"{os.fspath(result_path)} has {len(raw['stations_mm'])} and "
                             f"{len(res.model.config.tools)}")
    _header(page, res, raw, result_path, campaign_path, note)
    _motions_section(page, raw, k)
    _squareness_tools_stations(page, res, raw, k)
    _observability_section(page, raw)
    _volumetric_section(page, res, k)
    _residual_section(page, res, raw, data, campaign_path)
