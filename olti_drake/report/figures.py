"""Figures in the manner of paper 000 (matplotlib, PNG, no display needed).

Units on every axis: mm, mdeg, and µm for positioning errors. Reflectors are labelled P0, P1, ... as
the ``reflector`` index j of the campaign file and the result's ``P{j}_x_mm`` (paper 000 counts P_1..P_3).
"""

import os

import numpy as np

from olti_drake.io.outputs import make_dir, save_figure


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")  # headless: files only
    import matplotlib.pyplot as plt
    return plt


def plot_poses_and_reflectors(setup, campaign, path):
    """Command positions p*(k) and reflector positions, as 000 Fig. 5."""
    from olti_drake.model.scara import forward_kinematics

    plt = _pyplot()
    r = setup.scenario.robot
    c = campaign.columns
    p = forward_kinematics(c["theta1_deg"], c["theta2_deg"], r.nominal_L1_mm, r.nominal_L2_mm)[0]
    fig, ax = plt.subplots(figsize=(9, 6))
    ax.plot(p[:, 0], p[:, 1], ".", color="k", ms=3, label="command positions p*(k)")
    lost = c["valid"] < 0.5
    if lost.any():
        ax.plot(p[lost, 0], p[lost, 1], "x", color="tab:orange", label="beam lost")
    P, P_est = setup.reflectors_mm, setup.reflectors_estimate_mm
    ax.plot(P[:, 0], P[:, 1], "o", mfc="none", color="tab:red", ms=10, label="reflectors (true)")
    ax.plot(P_est[:, 0], P_est[:, 1], "+", color="tab:blue", ms=10, label="reflectors (estimate)")
    for j, q in enumerate(P):
        ax.annotate(f"P{j}", q, textcoords="offset points", xytext=(8, 8))
    ax.plot([0], [0], "s", color="gray", label="J1 axis")
    ax.set(xlabel="X, mm", ylabel="Y, mm", title="Command positions and reflectors (000 Fig. 5)")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1))
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_truth_maps(setup, path):
    """The simulated truth Δθ(θ*, ±1) of J1 and J2, as 000 Fig. 6 (continuous + grid samples)."""
    plt = _pyplot()
    r = setup.scenario.robot
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, axis, cmds in ((axes[0], "J1", setup.plan.theta1_deg), (axes[1], "J2", setup.plan.theta2_deg)):
        dev = getattr(r, axis)
        nodes = np.unique(cmds[setup.plan.measure])
        dense = np.linspace(nodes[0], nodes[-1], 400)
        for d, color, label in ((1, "tab:red", "positive (+1)"), (-1, "tab:blue", "negative (-1)")):
            ax.plot(dense, 1e3 * dev(dense, d), color=color, label=f"truth, {label}")
            ax.plot(nodes, 1e3 * dev(nodes, d), "o", color=color, ms=4)
        ax.set(xlabel=f"{axis} command angle, deg", ylabel="angular positioning deviation, mdeg",
               title=f"{axis}: simulated truth (000 Fig. 6 style)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


#: The files :func:`write_campaign_figures` writes.
CAMPAIGN_FIGURES = ("fig5_poses_reflectors.png", "fig6_truth_maps.png")


def write_campaign_figures(setup, campaign, out_dir):
    """Write the campaign's figures (:data:`CAMPAIGN_FIGURES`) into ``out_dir``; returns their paths."""
    make_dir(out_dir)
    fig5, fig6 = (os.path.join(out_dir, n) for n in CAMPAIGN_FIGURES)
    return [plot_poses_and_reflectors(setup, campaign, fig5), plot_truth_maps(setup, fig6)]


# -- identification and validation (000 Figs. 6, 9-11) ---------------------------------------------
_DIRECTIONS = ((1, "tab:red", "positive (+1)"), (-1, "tab:blue", "negative (-1)"))
_PASSES = ((1, "tab:red", "forward pass (+1)"), (-1, "tab:blue", "return pass (-1)"))


def _save(fig, plt, path):
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def _gauge_node(grid_deg) -> float:
    """Where the identification fixes the J1 rotation: θ1* = 0 clipped into the grid (deg)."""
    return float(np.clip(0.0, grid_deg[0], grid_deg[-1]))


def plot_identified_maps(ident, truth, path, std=None, method=None):
    """Identified Δθ_map(θ*, ±1) of J1 and J2 with k = 1 error bars, as 000 Fig. 6.

    ``ident``: an error-map :class:`~olti_drake.estimation.identification.Identification`
    (deviations and ``ident.std`` in deg, plotted in mdeg). ``truth``: the
    simulated robot (TrueRobot, or a campaign Setup) to overlay as continuous
    curves, or None. The J1 truth is shifted by the gauge constant -- its mean
    of (+1, -1) at θ1* = 0 -- because the identification fixes that level to 0
    (a rotation about J1 is unobservable); J2 needs no shift.

    ``std``: standard uncertainties (k = 1, deg; layout of ``ident.names``)
    for the error bars instead of ``ident.std`` -- e.g. from ``olti
    uncertainty`` with a budget (000 §5) -- and ``method`` names them in the legend.
    """
    plt = _pyplot()
    robot = getattr(truth, "robot", truth)  # a Setup carries its TrueRobot
    std = dict(zip(ident.names, ident.std if std is None else std))
    bar = "error bar u (k = 1)" + (f", {method}" if method else "")
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, axis, m, label in ((axes[0], "J1", ident.model.map1, "a"), (axes[1], "J2", ident.model.map2, "b")):
        g = m.grid_deg
        shift, note = 0.0, ""
        if robot is not None and axis == "J1":
            at = _gauge_node(g)
            shift = float(np.mean(robot.deviation("J1")(np.array([at, at]), np.array([1.0, -1.0]))))
            note = f" - {1e3 * shift:.2f} mdeg (gauge: mean at {at:g} deg = 0)"
        for d, color, name in _DIRECTIONS:
            block = "forward" if d > 0 else "reverse"
            u = np.array([std[f"{axis}_{block}_deg[{i}]"] for i in range(m.n_nodes)])
            values = m.forward_deg if d > 0 else m.reverse_deg
            ax.errorbar(g, 1e3 * values, yerr=1e3 * u, fmt="o", color=color, ms=4, capsize=3,
                        label=f"identified, {name}, {bar}")
            if robot is not None:
                dense = np.linspace(g[0], g[-1], 400)
                ax.plot(dense, 1e3 * (robot.deviation(axis)(dense, d) - shift), color=color, lw=1, alpha=0.6,
                        label=f"truth, {name}{note}")
        ax.set(xlabel=f"{axis} command angle θ{axis[1]}*, deg", ylabel="angular positioning deviation, mdeg",
               title=f"{label}) {axis}: identified bidirectional deviation (000 Fig. 6{label})")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    return _save(fig, plt, path)


def plot_path_deviation(xy_cmd_mm, pass_dir, measured_mm, dh_mm, errormap_mm, path):
    """E_YY and E_XY along a Y-path (X = 200 mm in 000): measured vs model, as 000 Figs. 9-10.

    All positions (N, 2) mm; ``pass_dir`` (N,) +1/-1 (forward/return pass).
    Columns: E_YY = y - y* (Fig. 9), E_XY = x - x* (Fig. 10), in µm vs the
    command Y (mm). Rows: a) D-H model (green ○), b) error-map model (○ red/blue).
    Measured: × red/blue by direction.
    """
    plt = _pyplot()
    cmd, meas = np.asarray(xy_cmd_mm), np.asarray(measured_mm)
    y = cmd[:, 1]
    fig, axes = plt.subplots(2, 2, figsize=(12, 7.5), sharex=True)
    for col, (c, name, fig_no) in enumerate(((1, "E_YY = y - y*", 9), (0, "E_XY = x - x*", 10))):
        for row, (label, model, pred) in enumerate((("a", "D-H model", dh_mm), ("b", "error-map model", errormap_mm))):
            ax = axes[row, col]
            for d, color, dname in _PASSES:
                s = np.asarray(pass_dir) == d
                ax.plot(y[s], 1e3 * (meas[s, c] - cmd[s, c]), "x", color=color, ms=6, label=f"measured, {dname}")
                if row == 1:
                    ax.plot(y[s], 1e3 * (pred[s, c] - cmd[s, c]), "o", mfc="none", color=color, ms=7,
                            label=f"error-map model, {dname}")
            if row == 0:
                ax.plot(y, 1e3 * (pred[:, c] - cmd[:, c]), "o", mfc="none", color="tab:green", ms=7,
                        label="D-H model")
            ax.set(ylabel=f"{name}, µm", title=f"Fig. {fig_no}{label}: measured vs {model}")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
        axes[1, col].set_xlabel("command Y, mm (X = %g mm)" % np.round(np.median(cmd[:, 0]), 3))
    return _save(fig, plt, path)


def plot_error_vectors(xy_cmd_mm, pass_dir, path_id, measured_mm, errormap_mm, dh_mm, path,
                       magnification: float = 1000.0, scale_um: float = 200.0):
    """Error vectors over the workspace, as 000 Fig. 11 (four panels).

    a) measured, b) error-map model, c) D-H model: the error vector from the
    command position (black dot) to the position; d) measured - error-map
    model, drawn from the command position. Positions (N, 2) mm; vectors
    magnified ``magnification`` times (1000: an error of ``scale_um`` = 200 µm
    is drawn 200 mm long, the "error scale"). Red/blue: forward/return pass
    (``pass_dir`` +1/-1); the magnified positions (○) of one pass of one path
    (``path_id``) are joined, as the paper's trajectories.
    """
    plt = _pyplot()
    cmd, meas = np.asarray(xy_cmd_mm), np.asarray(measured_mm)
    pass_dir, path_id = np.asarray(pass_dir), np.asarray(path_id)
    # What each panel's RMS is: only a) and d) involve the measurement; b) and c) are the size of the
    # deviation a model *predicts*, not how accurate it is (a model predicting nothing would score 0).
    panels = (("a) measured (tracker)", meas - cmd, "RMS of the measured error"),
              ("b) error-map model", errormap_mm - cmd, "RMS of the predicted deviation (not an accuracy)"),
              ("c) D-H model", dh_mm - cmd, "RMS of the predicted deviation (not an accuracy)"),
              ("d) measured - error-map model", meas - errormap_mm, "RMS of the model's prediction error"))
    fig, axes = plt.subplots(2, 2, figsize=(11, 13.5), sharex=True, sharey=True)
    for ax, (title, err, what) in zip(axes.ravel(), panels):
        tip = cmd + magnification * err
        for d, color, name in _PASSES:
            s = pass_dir == d
            # The vectors themselves, faint: the joined tips carry the message.
            ax.plot(np.stack([cmd[s, 0], tip[s, 0]]), np.stack([cmd[s, 1], tip[s, 1]]), "-", color=color,
                    lw=0.5, alpha=0.35)
            for i in np.unique(path_id[s]):
                k = s & (path_id == i)
                ax.plot(tip[k, 0], tip[k, 1], "o-", color=color, ms=2.5, lw=0.9, mfc="none",
                        label=name if i == path_id[s].min() else None)
        ax.plot(cmd[:, 0], cmd[:, 1], ".", color="k", ms=4, label="command positions")
        rms = 1e3 * np.sqrt(np.mean(np.sum(err ** 2, axis=1)))
        ax.set_title(f"{title}\n{what}: {rms:.1f} µm", fontsize=10)
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
    # The error scale: a bar of scale_um µm, magnified.
    ax = axes[0, 0]
    x0, y0 = cmd[:, 0].min(), cmd[:, 1].max() + 80
    ax.plot([x0, x0 + magnification * scale_um * 1e-3], [y0, y0], "k-", lw=2.5)
    ax.annotate(f"error scale: {scale_um:g} µm (x{magnification:g})", (x0, y0), textcoords="offset points",
                xytext=(0, 5), fontsize=8)
    ax.legend(fontsize=8, loc="lower left")
    for ax in axes[1]:
        ax.set_xlabel("X, mm")
    for ax in axes[:, 0]:
        ax.set_ylabel("Y, mm")
    fig.suptitle("Positioning error on paths not used in the identification (000 Fig. 11)")
    return _save(fig, plt, path)


# -- uncertainty of the identification (000 §5, Fig. 6 error bars; 001 §4.4, Fig. 14) ------------------
_APPROACHES = ((1.0, "approach +1 (both axes positive)"), (-1.0, "approach -1 (both axes negative)"))


def _sample_position_std(model, cmd, X, max_values: int = 4_000_000) -> np.ndarray:
    """Sample standard deviation (ddof = 1) of x, y (N, 2) mm over the robot parameter samples X (T, P).

    Positions of every sample by :meth:`ScaraModel.positions_batch`, in chunks
    of commands so that at most ``max_values`` positions are held at once.
    """
    from olti_drake.model.scara import JointCommands

    out = np.empty((len(cmd), 2))
    chunk = max(1, max_values // (2 * len(X)))
    for i in range(0, len(cmd), chunk):
        s = slice(i, i + chunk)
        sub = JointCommands(cmd.theta1_deg[s], cmd.theta2_deg[s], cmd.dir1[s], cmd.dir2[s])
        out[s] = model.positions_batch(sub, X).std(axis=0, ddof=1)
    return out


def prediction_uncertainty_map(ident, x, cov=None, samples=None, step_mm=None) -> dict:
    """Standard uncertainty (k = 1) of predicted positions over the workspace (001 §4.4, Fig. 14).

    ``ident``: the :class:`~olti_drake.estimation.identification.Identifier` of an
    error-map result, ``x`` its parameter vector. Either ``cov`` (n, n), the
    linear covariance (JCGM 100; through
    :func:`~olti_drake.estimation.uncertainty.prediction_std`), or ``samples`` (T, n), the
    Monte Carlo parameter samples (JCGM 101; the positions of every sample).
    At every point of :func:`~olti_drake.model.scara.workspace_grid` and for both approach
    directions (dir1 = dir2 = +1, then -1): u = sqrt(u_x² + u_y²) mm, the
    standard uncertainty of the 2-norm of the predicted-position error, as
    001 Fig. 14 plots (times k). In the result's gauge frame (rotation about
    J1 fixed as the result's ``gauge`` says).

    Returns dict: ``x_mm`` (nx,), ``y_mm`` (ny,), ``u_mm`` (2, ny, nx) with
    NaN outside the map range (index 0: approach +1, 1: approach -1),
    ``directions`` (+1, -1), ``reflectors_mm`` (Nt, 2).
    """
    from olti_drake.model.scara import JointCommands
    from olti_drake.estimation.uncertainty import prediction_std

    if (cov is None) == (samples is None):
        raise ValueError("prediction_uncertainty_map needs exactly one of cov and samples")
    model, P, _ = ident.split(np.asarray(x, dtype=float))
    if not model.is_errormap:
        raise ValueError("the prediction-uncertainty map needs an error-map result (model 'errormap')")
    from olti_drake.model.scara import workspace_grid

    L = model.L1_mm + model.L2_mm
    axis, inside, t1, t2 = workspace_grid(model.L1_mm, model.L2_mm, model.map1.grid_deg, model.map2.grid_deg,
                                          L / 40 if step_mm is None else step_mm)
    xs, ys = axis, axis
    u = np.full((2,) + inside.shape, np.nan)
    for i, (d, _) in enumerate(_APPROACHES):
        cmd = JointCommands(t1, t2, np.full(t1.size, d), np.full(t1.size, d))
        if not len(cmd):
            continue
        s = (prediction_std(ident, cov, x, cmd) if cov is not None else
             _sample_position_std(ident.robot0, cmd, np.asarray(samples)[:, :ident.n_robot]))
        u[i][inside] = np.hypot(s[:, 0], s[:, 1])
    return {"x_mm": xs, "y_mm": ys, "u_mm": u, "directions": tuple(d for d, _ in _APPROACHES),
            "reflectors_mm": np.asarray(P)}


def plot_prediction_uncertainty_map(pmap: dict, path, k: float = 2.0, method: str = ""):
    """The expanded uncertainty U(k) of predicted positions over the workspace, in the manner of 001 Fig. 14.

    ``pmap``: :func:`prediction_uncertainty_map`'s dict (mm). Colour: U =
    k · sqrt(u_x² + u_y²) in µm, one panel per approach direction on a shared
    colour scale; reflectors (▲ P0, P1, ...) and the J1 axis (■) marked.
    """
    plt = _pyplot()
    U = 1e3 * k * pmap["u_mm"]
    finite = np.isfinite(U)
    vmin, vmax = (float(np.min(U[finite])), float(np.max(U[finite]))) if finite.any() else (0.0, 1.0)
    xs, ys, P = pmap["x_mm"], pmap["y_mm"], pmap["reflectors_mm"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.9), sharex=True, sharey=True, layout="constrained")
    for i, (ax, (_, name)) in enumerate(zip(axes, _APPROACHES)):
        mesh = ax.pcolormesh(xs, ys, np.ma.masked_invalid(U[i]), shading="nearest", cmap="jet",
                             vmin=vmin, vmax=vmax)
        ax.plot(P[:, 0], P[:, 1], "^", color="k", mfc="white", ms=9, label="reflectors")
        for j, q in enumerate(P):
            ax.annotate(f"P{j}", q, textcoords="offset points", xytext=(7, 5), fontsize=9)
        ax.plot([0], [0], "s", color="gray", ms=7, label="J1 axis")
        stats = (f"max {np.nanmax(U[i]):.1f} µm, mean {np.nanmean(U[i]):.1f} µm" if np.isfinite(U[i]).any()
                 else "no point inside the map range")
        ax.set_title(f"{name}\nU (k = {k:g}): {stats}", fontsize=10)
        ax.set_xlabel("X, mm")
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("Y, mm")
    axes[0].legend(fontsize=8, loc="upper left")
    lo = min(np.min(xs), np.min(P[:, 0]) if len(P) else 0.0) - 30
    hi = max(np.max(xs), np.max(P[:, 0]) if len(P) else 0.0) + 30
    axes[0].set_xlim(lo, hi)
    axes[0].set_ylim(min(np.min(ys), np.min(P[:, 1]) if len(P) else 0.0) - 30,
                     max(np.max(ys), np.max(P[:, 1]) if len(P) else 0.0) + 30)
    fig.colorbar(mesh, ax=list(axes), shrink=0.9,
                 label=f"U (k = {k:g}) of the predicted position, k·sqrt(u_x² + u_y²), µm")
    fig.suptitle("Uncertainty of predicted positions inside the identified map range (001 Fig. 14 style)"
                 + (f" -- {method}" if method else ""), fontsize=11)
    save_figure(fig, path)
    plt.close(fig)
    return path


# -- the machine-tool case of 001 (Figs. 6-7, 10, 13, 14) ---------------------------------------------
def _perimeter_order(points_mm) -> np.ndarray:
    """Indices that walk points around their centroid (to draw a closed target loop)."""
    p = np.asarray(points_mm, dtype=float)
    rel = p - p.mean(axis=0)
    order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
    return np.append(order, order[0])


def _station_names(n: int):
    return [f"Pos {chr(ord('A') + j)}" for j in range(n)]


def plot_machine_targets(commands_mm, stations_mm, estimates_mm, path, station_estimates_mm=None,
                         scale_mm=None, truth_mm=None, magnification: float = 2000.0, scale_um: float = 5.0,
                         stations_label: str = "stations (true table axis)"):
    """Command and estimated target positions with the stations, as 001 Fig. 10.

    a) the layout: command positions, the stations Pos A, B, ... (▲, ``stations_label`` says which:
    the true table axes of a simulation, or the identified ones of a result; §2.2 estimate +).
    b) the targets: errors from the commands magnified ``magnification`` times (2,000 in 001) -- the
    multilateration estimate, the 2D digital scale (``scale_mm``) and the simulated truth (``truth_mm``),
    all (N, 2) mm in the best-fit gauge; a bar of ``scale_um`` µm gives the scale. The title names
    the digital-scale comparison only when ``scale_mm`` is drawn.
    """
    plt = _pyplot()
    c, S = np.asarray(commands_mm, dtype=float), np.asarray(stations_mm, dtype=float)
    fig, axes = plt.subplots(1, 2, figsize=(14, 6.6), gridspec_kw={"width_ratios": [1, 1.15]})
    ax = axes[0]
    loop = _perimeter_order(c)
    ax.plot(c[loop, 0], c[loop, 1], "k.-", lw=0.6, ms=6, label="command target positions")
    ax.plot(S[:, 0], S[:, 1], "^", color="tab:green", ms=11, label=stations_label)
    if station_estimates_mm is not None:
        E = np.asarray(station_estimates_mm, dtype=float)
        ax.plot(E[:, 0], E[:, 1], "+", color="k", ms=14, mew=1.5, label="initial estimates (001 §2.2)")
    for name, q in zip(_station_names(len(S)), S):
        ax.annotate(name, q, textcoords="offset points", xytext=(9, 6), fontsize=11)
    ax.set(xlabel="X, mm", ylabel="Y, mm", title="a) Command target positions and tracking interferometer positions")
    ax.set_aspect("equal")
    ax.margins(0.12)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=9, loc="upper left")

    ax = axes[1]
    ax.plot(c[loop, 0], c[loop, 1], "k.:", lw=0.6, ms=6, label="command target positions")
    series = [(estimates_mm, "o-", "tab:red", "estimated by the 'open-loop' tracking interferometer")]
    if scale_mm is not None:
        series.append((scale_mm, "s--", "tab:blue", "measured by the 2D digital scale"))
    if truth_mm is not None:
        series.append((truth_mm, "-", "0.55", "simulation truth"))
    for pts, style, color, label in series:
        tip = c + magnification * (np.asarray(pts, dtype=float) - c)
        ax.plot(tip[loop, 0], tip[loop, 1], style, color=color, ms=5, mfc="none", lw=1.2, label=label)
    x0, y0 = c[:, 0].min(), c[:, 1].min() - 0.22 * np.ptp(c[:, 1])
    bar = magnification * 1e-3 * scale_um
    ax.plot([x0, x0 + bar], [y0, y0], "k-", lw=3)
    ax.annotate(f"{scale_um:g} µm (errors ×{magnification:g})", (x0 + bar, y0), textcoords="offset points",
                xytext=(6, -4), fontsize=9)
    ax.set(xlabel="X, mm", ylabel="Y, mm", title=f"b) Target positions, errors from the commands ×{magnification:g}")
    ax.set_aspect("equal")
    ax.margins(0.1)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, -0.1), ncol=2)
    fig.suptitle("Target positions estimated by multilateration" + (" vs the 2D digital scale" if scale_mm is not None
                                                                     else "") + " (001 Fig. 10)")
    return _save(fig, plt, path)


def plot_linear_errors(panels, path):
    """Linear positioning errors along lines, multilateration vs a linear laser interferometer (001 Fig. 13).

    ``panels``: dicts with ``title``, ``xlabel``, ``ylabel``; ``position_mm``, ``estimate_um`` and
    ``expanded_um`` (U, k = 2: the error bars) of the multilateration; ``laser_position_mm``,
    ``laser_um`` (and optional ``laser_bound_um``, 001 Table 1) of the interferometer; optional
    ``truth_um``. Errors in µm, offsets already removed by the caller.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.8), squeeze=False)
    for ax, p in zip(axes[0], panels):
        ax.errorbar(p["position_mm"], p["estimate_um"], yerr=p["expanded_um"], fmt="o", color="tab:red", ms=6,
                    capsize=4, label="'open-loop' tracking interferometer, U (k = 2)")
        ax.errorbar(p["laser_position_mm"], p["laser_um"], yerr=p.get("laser_bound_um"), fmt="x-",
                    color="tab:blue", ms=8, capsize=3, label="linear laser interferometer (Table 1 ±)")
        if p.get("truth_um") is not None:  # a wide light band under the others: the laser lies on it
            ax.plot(p["position_mm"], p["truth_um"], "-", color="0.5", lw=6, alpha=0.3, zorder=0,
                    label="simulation truth (on the estimate's line)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel=p["xlabel"], ylabel=p["ylabel"], title=p["title"])
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Linear positioning errors: multilateration vs laser interferometer, offsets removed (001 Fig. 13)")
    return _save(fig, plt, path)


def plot_target_uncertainty(commands_mm, expanded_um, path, k: float = 2.0, method: str = ""):
    """Expanded uncertainty U(k) of each estimated target position, colour-coded at it (001 Fig. 14).

    ``expanded_um`` (N,): k·sqrt(u_x² + u_y²), µm, of the targets at ``commands_mm`` (N, 2) mm. In 3D
    (N, 3) commands and k·sqrt(u_x² + u_y² + u_z²): the volume as slices at a few Z command levels.
    """
    plt = _pyplot()
    c, U = np.asarray(commands_mm, dtype=float), np.asarray(expanded_um, dtype=float)
    if c.shape[1] == 3:
        return _target_uncertainty_slices(plt, c, U, path, k, method)
    fig, ax = plt.subplots(figsize=(7.6, 6.4))
    sc = ax.scatter(c[:, 0], c[:, 1], c=U, s=520, marker="s", cmap="jet", edgecolors="k")
    for q, v in zip(c, U):
        ax.annotate(f"{v:.1f}", q, ha="center", va="center", fontsize=8, color="w", fontweight="bold")
    ax.set(xlabel="X, mm", ylabel="Y, mm",
           title=f"U (k = {k:g}) of the estimated target positions: max {U.max():.1f} µm, mean {U.mean():.1f} µm"
           + (f"\n{method}" if method else ""))
    ax.set_aspect("equal")
    ax.margins(0.12)
    ax.grid(True, alpha=0.3)
    fig.colorbar(sc, ax=ax, label=f"U (k = {k:g}) = k·sqrt(u_x² + u_y²), µm")
    fig.suptitle("Uncertainty of the estimated target positions (001 Fig. 14)")
    return _save(fig, plt, path)


def _target_uncertainty_slices(plt, c, U, path, k, method, most: int = 4):
    """001 Fig. 14 in 3D: one XY panel per Z command level (at most ``most``, spread over the levels), one
    colour scale; targets of several tools at one command show their largest U."""
    levels = np.unique(np.round(c[:, 2], 6))
    shown = levels[np.unique(np.round(np.linspace(0, len(levels) - 1, min(most, len(levels)))).astype(int))]
    fig, axes = plt.subplots(1, len(shown), figsize=(5.2 * len(shown) + 1.5, 5.0), squeeze=False)
    norm = plt.Normalize(U.min(), U.max())
    for ax, z in zip(axes[0], shown):
        at = np.abs(c[:, 2] - z) < 1e-6
        sc = ax.scatter(c[at, 0], c[at, 1], c=U[at], norm=norm, s=260, marker="s", cmap="jet", edgecolors="k")
        for q, v in zip(c[at], U[at]):
            ax.annotate(f"{v:.1f}", q[:2], ha="center", va="center", fontsize=7, color="w", fontweight="bold")
        ax.set(xlabel="X, mm", ylabel="Y, mm", title=f"Z command {z:g} mm")
        ax.set_aspect("equal")
        ax.margins(0.12)
        ax.grid(True, alpha=0.3)
    fig.colorbar(sc, ax=axes[0][-1], label=f"U (k = {k:g}) = k·sqrt(u_x² + u_y² + u_z²), µm")
    fig.suptitle(f"Uncertainty of the estimated target positions (001 Fig. 14, slices of the volume): "
                 f"max {U.max():.1f} µm, mean {U.mean():.1f} µm" + (f"\n{method}" if method else ""))
    return _save(fig, plt, path)


def plot_station_estimation(centres, zeros, path):
    """The initial estimation of 001 §2.2, one line per station.

    a), b) Fig. 6: displacement vs table angle while centring the target (``centres``:
    CentreEstimate list) -- the first sweep, then the last (what is left: radial error motion and
    noise). c) Fig. 7: displacement vs Y across the beam while aligning the zero angle (``zeros``:
    ZeroAngleEstimate list), first and last sweep. Readings µm with their mean removed.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, (name, ce, ze) in enumerate(zip(_station_names(len(centres)), centres, zeros)):
        col = colors[j % len(colors)]
        (a0, d0), (a1, d1) = ce.sweeps[0], ce.sweeps[-1]
        axes[0].plot(a0, d0, "-", color=col, lw=1.2, label=f"{name}: target put near the axis")
        axes[1].plot(a1, d1, "-", color=col, lw=1.2,
                     label=f"{name}: after {ce.iterations - 1} moves (error {np.hypot(*ce.error_um):.1f} µm)")
        (y0, e0), (y1, e1) = ze.sweeps[0], ze.sweeps[-1]
        axes[2].plot(y0 - y0.mean(), e0, "--", color=col, lw=1, label=f"{name}: first setting")
        axes[2].plot(y1 - y1.mean(), e1, "-", color=col, lw=1.5,
                     label=f"{name}: final ({1e6 * ze.error_rad:+.0f} µrad off, u {1e6 * ze.std_rad:.0f} µrad)")
    axes[0].set(xlabel="table angle, deg", ylabel="displacement − mean, µm",
                title="a) Centring (001 Fig. 6): first sweep")
    axes[1].set(xlabel="table angle, deg", ylabel="displacement − mean, µm",
                title="b) Centring: last sweep (radial error motion, noise)")
    axes[2].set(xlabel="Y across the beam, mm", ylabel="displacement − mean, µm",
                title="c) Zero angle (001 Fig. 7): beam normal to the Y line")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Initial estimation of the station positions and zero angles (001 §2.2)")
    return _save(fig, plt, path)
