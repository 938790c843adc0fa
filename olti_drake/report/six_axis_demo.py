"""``olti demo --robot six_axis``: the six-axis story end to end (issue "Six-axis campaigns end to end", item 5).

1. simulate the shipped six-axis campaign (``diagrams/six_axis.yaml``: UR5, four floor tracers)
   through the Drake diagram (:mod:`olti_drake.sim.serial_station`): ``campaign.csv``, ``truth.json``;
2. identify the geometric (``dh``) and the error-map (``errormap``) models from the campaign file
   (:func:`olti_drake.estimation.serial_identification.identify_serial`, as ``olti identify --robot``):
   ``result_dh.json``, ``result_errormap.json``;
3. compare them with the nominal model on poses never measured (seeded, within the plan's ranges,
   random approach directions), measured by a simulated laser tracker in 3D (AT960-class,
   U = 15 µm + 6 µm/m at k = 2, per coordinate U/(k√3), in its own frame): each model's predicted
   tool points are fitted to the tracker's by a rigid motion (the tracker frame and the
   identification's gauge are both unknown rigid motions), and the errors left are the model's;
4. figures: the identified maps per joint with ±2u error bars against the truth (000 Fig. 6 style),
   the 3D error vectors at the unseen poses before and after calibration (magnified, 000 Fig. 11
   style), the identification residuals.

Units: mm and degrees in files; µm and mdeg on the figures where the names say so.
"""

import os
import time

import numpy as np

from olti_drake.io.resources import shipped
from olti_drake.model.frames import rigid_fit

#: Files the demo writes besides campaign.csv and truth.json (results and figures: replaced only with --force).
RESULTS = ("result_dh.json", "result_errormap.json", "validation.json", "six_axis_maps.png",
           "six_axis_errors.png", "six_axis_residuals.png")
N_UNSEEN = 300
TRACKER_MM = (-2000.0, 0.0, 0.0)
TRACKER_U_UM = (15.0, 6.0, 2.0)  # constant, per metre, coverage factor (000 §4.3's AT960-XR)


def default_scenario_path() -> str:
    """The shipped six-axis scenario (installed package or source checkout)."""
    path = shipped("diagrams", "six_axis.yaml")
    if not path.is_file():
        raise ValueError(f"{path}: the shipped six-axis scenario is missing from this installation")
    return str(path)


def run_six_axis_demo(out_dir, force: bool = False, scenario_path=None, scenario_text=None) -> list:
    """Run the demo into ``out_dir`` (module doc); returns the lines it reports."""
    from olti_drake.io.outputs import preflight
    from olti_drake.sim import serial_station as ss
    from olti_drake.sim.serial_scenario import load_serial_scenario

    t0 = time.perf_counter()
    path = scenario_path or default_scenario_path()
    scenario = load_serial_scenario(path, None, scenario_text)
    preflight([os.path.join(out_dir, n) for n in RESULTS], [path, scenario.robot_path()], force=force,
              measurements=[os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json")], dirs=[out_dir],
              create_dirs=True)
    setup = ss.prepare_serial(scenario)
    campaign = ss.run_serial_campaign(setup)
    csv_path, truth_path = ss.write_serial_simulation(campaign, out_dir, [f"olti demo --robot six_axis: {path}"])
    lines = ["six-axis campaign, simulated (UR5-class arm, floor tracers aimed open loop; docs/six_axis_campaign.md)"]
    lines += ss.serial_summary(setup, campaign, time.perf_counter() - t0)
    lines.append(f"wrote {csv_path} and {truth_path}")
    idents = _identify(setup, csv_path, out_dir, lines)
    table = _validate(setup, idents)
    lines += _table_lines(table)
    _write_validation(table, os.path.join(out_dir, "validation.json"), force)
    lines += [f"wrote {p}" for p in _figures(setup, idents, table, out_dir)]
    lines.append(f"demo done in {time.perf_counter() - t0:.1f} s")
    return lines


def _identify(setup, csv_path, out_dir, lines) -> dict:
    from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial, summary
    from olti_drake.io.serial_io import read_serial_campaign, serial_result_dict, write_serial_result

    s = setup.scenario
    robot = s.robot.file
    data = read_serial_campaign(csv_path, setup.n_joints, robot=robot)
    out = {}
    for kind in ("dh", "errormap"):
        options = SerialIdentificationOptions(model=kind, tool_offset_mm=tuple(setup.tool_offset_mm),
                                              grid_step_deg=s.plan.step_deg, budget=setup.budget)
        ident = identify_serial(setup.chain, data, options)
        path = os.path.join(out_dir, f"result_{kind}.json")
        write_serial_result(path, serial_result_dict(kind=kind, robot_file=robot, measurement=ident.measurement,
                                                     fit=ident.fit, gauge=ident.gauge, campaign_digest=data.digest(),
                                                     notes=ident.notes))
        lines += ["", f"identified {kind} model:", summary(ident), f"wrote {path}"]
        out[kind] = ident
    return out


def tracker_points(p_true_mm, rng) -> np.ndarray:
    """A 3D laser tracker's readings of true points (M, 3) mm: per coordinate u = U(d)/(k√3),
    U(d) = 15 µm + 6 µm/m · d (k = 2), d the distance from the tracker (000 §4.3 in 3D)."""
    u_const, u_per_m, k = TRACKER_U_UM
    d_m = np.linalg.norm(p_true_mm - np.asarray(TRACKER_MM), axis=1) * 1e-3
    u_mm = (u_const + u_per_m * d_m) / (k * np.sqrt(3.0)) * 1e-3
    return p_true_mm + u_mm[:, None] * rng.standard_normal(p_true_mm.shape)


def fitted_errors(p_mm, q_mm) -> np.ndarray:
    """The residual vectors q − (R p + t) (M, 3) mm after the rigid fit (:func:`~olti_drake.model.frames.rigid_fit`)
    of predicted points p to tracker points q: the tracker's frame taken out."""
    R, t = rigid_fit(p_mm, q_mm)
    return q_mm - (p_mm @ R.T + t)


def _unseen(setup):
    """Seeded unseen poses within the plan's node range of each joint, random approach directions."""
    rng = np.random.default_rng([setup.scenario.seed, 14])
    g = [setup.plan.grids[j] for j in setup.chain.joint_names]
    cmd = np.column_stack([rng.uniform(x[0], x[-1], N_UNSEEN) for x in g])
    return cmd, rng.choice([-1.0, 1.0], cmd.shape), rng


def _validate(setup, idents) -> dict:
    cmd, dirs, rng = _unseen(setup)
    true = setup.truth.positions(cmd, dirs)
    measured = tracker_points(true, rng)
    predicted = {"nominal": setup.chain.positions(cmd, setup.chain.nominal_parameters(setup.tool_offset_mm))}
    for kind, ident in idents.items():
        model = ident.model
        predicted[kind] = model.positions(cmd, dirs, ident.fit.x[:model.n_params])
    table = {"n_poses": N_UNSEEN, "commands_deg": cmd, "dirs": dirs, "models": {}}
    for name, p in predicted.items():
        err = fitted_errors(p, measured)
        e = np.linalg.norm(err, axis=1)
        table["models"][name] = {"rms_mm": float(np.sqrt(np.mean(e ** 2))), "max_mm": float(e.max()), "errors": err}
    return table


def _table_lines(table) -> list:
    lines = ["", f"prediction on {table['n_poses']} unseen poses measured by a simulated laser tracker "
                 f"(best-fit rigid motion into its frame; errors |tracker - model|):"]
    for name, m in table["models"].items():
        lines.append(f"  {name:<9} RMS {1e3 * m['rms_mm']:8.1f} um   max {1e3 * m['max_mm']:8.1f} um")
    return lines


def _write_validation(table, path, force):
    from olti_drake.io.outputs import write_json

    write_json(path, {"n_poses": table["n_poses"], "tracker_mm": list(TRACKER_MM),
                      "tracker_U_um": {"constant": TRACKER_U_UM[0], "per_m": TRACKER_U_UM[1], "k": TRACKER_U_UM[2]},
                      "models": {k: {"rms_mm": v["rms_mm"], "max_mm": v["max_mm"]}
                                 for k, v in table["models"].items()}})


def _figures(setup, idents, table, out_dir) -> list:
    from olti_drake.io.outputs import save_figure

    import matplotlib
    matplotlib.use("Agg")  # headless: files only
    import matplotlib.pyplot as plt

    paths = []
    for name, fig in (("six_axis_maps.png", _maps_figure(plt, setup, idents["errormap"])),
                      ("six_axis_errors.png", _errors_figure(plt, setup, table)),
                      ("six_axis_residuals.png", _residuals_figure(plt, idents))):
        fig.tight_layout()
        path = os.path.join(out_dir, name)
        save_figure(fig, path)
        plt.close(fig)
        paths.append(path)
    return paths


def _maps_figure(plt, setup, ident):
    """Identified maps per joint (forward/reverse, ±2u) and the truth's deviations shifted to the same
    mean: a map's level trades with the location errors and the gauge, its shape and backlash do not."""
    model, fit = ident.model, ident.fit
    n = len(model.maps)
    fig, axes = plt.subplots((n + 2) // 3, 3, figsize=(14, 3.4 * ((n + 2) // 3)), squeeze=False)
    for ax, start, m in zip(axes.ravel(), model.map_starts, model.maps):
        g = m.emap.grid_deg
        k = len(g)
        vals, std = fit.x[start:start + m.n_values] * 1e3, fit.std[start:start + m.n_values] * 1e3
        dev = setup.truth.deviations[list(setup.chain.joint_names).index(m.joint)]
        fine = np.linspace(g[0], g[-1], 400)
        shift = np.mean(vals) - 1e3 * np.mean(np.concatenate([dev(g, 1.0), dev(g, -1.0)]))
        for b, (sign, color, label) in enumerate(((1.0, "tab:red", "+1"), (-1.0, "tab:blue", "-1"))):
            ax.errorbar(g, vals[b * k:(b + 1) * k], yerr=2 * std[b * k:(b + 1) * k], fmt="o", ms=3, color=color,
                        capsize=2, label=f"identified {label} (±2u)")
            ax.plot(fine, 1e3 * dev(fine, sign) + shift, "-", color=color, lw=0.8, alpha=0.6, label=f"truth {label}")
        ax.set_title(m.joint, fontsize=9)
        ax.set_xlabel("commanded angle (deg)")
        ax.set_ylabel("deviation (mdeg)")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle("Identified bidirectional error maps vs the simulated truth (truth shifted to the same mean level)")
    return fig


def _errors_figure(plt, setup, table):
    """Error vectors at the unseen poses, nominal vs error-map model, magnified (000 Fig. 11 style)."""
    cmd, dirs = table["commands_deg"], table["dirs"]
    p = setup.truth.positions(cmd, dirs)
    fig = plt.figure(figsize=(13, 6))
    for i, name in enumerate(("nominal", "errormap")):
        err = table["models"][name]["errors"]
        scale = 100.0 / max(np.linalg.norm(table["models"]["nominal"]["errors"], axis=1).max(), 1e-9)
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], *(err * scale).T, color="tab:red" if i == 0 else "tab:green", lw=0.8)
        ax.scatter(*p.T, s=2, color="k")
        m = table["models"][name]
        ax.set_title(f"{name}: RMS {1e3 * m['rms_mm']:.0f} um, max {1e3 * m['max_mm']:.0f} um "
                     f"(arrows x{scale:.0f})", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
    return fig


def _residuals_figure(plt, idents):
    fig, ax = plt.subplots(figsize=(7, 4))
    for kind, color in (("dh", "tab:orange"), ("errormap", "tab:green")):
        r = idents[kind].fit.residuals * 1e3
        ax.hist(r, bins=60, alpha=0.6, color=color, label=f"{kind}: RMS {np.sqrt(np.mean(r ** 2)):.2f} um")
    ax.set_xlabel("residual (um)")
    ax.set_ylabel("readings")
    ax.legend()
    ax.set_title("Identification residuals of the six-axis campaign")
    return fig
