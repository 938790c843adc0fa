"""The SCARA of paper 000 in ``olti identify`` (its summary), ``predict``, ``uncertainty``, ``design`` and
``compensate``: argument handling and printing only (the verbs dispatch here by the result's kind, :mod:`olti_drake.cli.kinds`); the work is in
:mod:`olti_drake.estimation` and :mod:`olti_drake.io`. Units: mm and degrees."""

import os
import sys
import time


def preflight(files, inputs, dirs=(), args=None):
    from olti_drake.io.outputs import preflight as check

    check(files, inputs, force=getattr(args, "force", False), dirs=dirs, create_dirs=bool(dirs))


def identification_summary(ident) -> str:
    """Parameters ± standard uncertainty (k = 1), residual RMS, iterations, conditioning (a SCARA identification:
    olti identify, olti demo)."""
    import numpy as np

    from olti_drake.estimation.calibration import suspect_readings_line

    m = ident.model
    u = {n: s for n, s in zip(ident.names, ident.std)}
    lines = [f"model {'errormap' if m.is_errormap else 'dh'}: {ident.n_readings} readings, "
             f"{len(ident.names)} parameters, solver {ident.solver}",
             f"  L1 = {m.L1_mm:.4f} +- {u['L1_mm']:.4f} mm, L2 = {m.L2_mm:.4f} +- {u['L2_mm']:.4f} mm (k = 1)"]
    if m.is_errormap:
        for axis, mp in (("J1", m.map1), ("J2", m.map2)):
            s = np.array([u[n] for n in ident.names if n.startswith(axis + "_")])
            back = mp.forward_deg - mp.reverse_deg
            lines.append(f"  {axis} map: {mp.n_nodes} nodes {mp.grid_deg[0]:g}..{mp.grid_deg[-1]:g} deg, "
                         f"deviation {1e3 * mp.values.min():.2f}..{1e3 * mp.values.max():.2f} mdeg, "
                         f"mean backlash {1e3 * back.mean():.2f} mdeg, u up to {1e3 * s.max():.3f} mdeg")
    else:
        lines.append(f"  theta20 = {1e3 * m.theta20_deg:.3f} +- {1e3 * u['theta20_deg']:.3f} mdeg")
    for j, (p, d0) in enumerate(zip(ident.reflectors_mm, ident.dead_paths_mm)):
        lines.append(f"  P{j} = ({p[0]:.3f}, {p[1]:.3f}) mm, d0_{j} = {d0:.3f} mm")
    lines.append(f"  residual RMS {1e3 * ident.residual_rms_mm:.2f} um, {ident.iterations} iterations, "
                 f"condition number {ident.condition_number:.3g} (scaled, within the gauge)")
    lines.append(f"  gauge: {ident.gauge}")
    for note in ident.notes:
        lines.append(f"  note: {note}")
    res = getattr(ident, "resolution", None)
    if res and res.get("done"):
        lines.append(f"  resolution check: held-out readings at alternate nodes missed by the map on the others by RMS "
                     f"{1e3 * res['held_out_rms_mm']:.1f} um ({res['ratio']:.1f} x the budget's reading u)")
    elif res:
        lines.append(f"  resolution check not possible: {res['why']}")
    for warning in getattr(ident, "warnings", []):
        lines.append(f"  warning: {warning}")
    lines += [t for t in [suspect_readings_line(ident.outliers)] if t]
    return "\n".join(lines)


def predict(args) -> int:
    """Predicted actual positions (000 Eq. 3 with Eq. 7) for commanded angles and directions."""
    from olti_drake.io.csvio import load_commands, write_table
    from olti_drake.io.result import load_result
    from olti_drake.model.errormap import OutsideGridError

    model, _, _, _ = load_result(args.result, outside=args.outside)
    cmd, lines = load_commands(args.commands)
    if cmd.one_directional and model.is_errormap and model.bidirectional:
        raise ValueError(f"{args.commands}: missing required column 'dir1' ({args.result} has bidirectional error "
                         f"maps: the approach directions dir1, dir2 are needed)")
    try:
        p = model.positions(cmd)
    except OutsideGridError as e:
        raise ValueError(f"{args.commands}:{lines[e.row]}: {e} -- or run with --outside clamp") from None
    cols = {"theta1_deg": cmd.theta1_deg, "theta2_deg": cmd.theta2_deg}
    if not cmd.one_directional:  # the prediction repeats the file's columns (formats.md)
        cols.update({"dir1": cmd.dir1, "dir2": cmd.dir2})
    cols.update({"x_mm": p[:, 0], "y_mm": p[:, 1]})
    write_table(args.out, cols, {"dir1": "%d", "dir2": "%d", "x_mm": "%.6f", "y_mm": "%.6f"},
                comments=[f"olti predict: {args.result} applied to {args.commands}; mm and degrees"])
    print(f"predicted {len(cmd)} positions; wrote {args.out}")
    return 0


def uncertainty(args) -> int:
    """Uncertainty of a SCARA result from its campaign and a budget (000 §5): linear (JCGM 100) or Monte Carlo
    (JCGM 101); writes the formats.md ``uncertainty`` object (k = 1, plus ``expanded``); mm and degrees."""
    import types

    import numpy as np

    from olti_drake.cli.propagate import campaign_note, propagate
    from olti_drake.estimation.identification import identifier_at_result
    from olti_drake.estimation.uncertainty import uncertainty_dict
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.csvio import check_campaign_matches, load_campaign, read_json
    from olti_drake.io.outputs import write_json
    from olti_drake.model.budget import ReadingErrors
    from olti_drake.report.figures import plot_identified_maps, plot_prediction_uncertainty_map, prediction_uncertainty_map

    budget = budget_or_default(args.budget, "scara")
    data = load_campaign(args.campaign)
    note = check_campaign_matches(read_json(args.result, None), data, args.result)
    ident, x = identifier_at_result(args.result, data)
    model = ident.split(x)[0]
    if (args.map or args.maps) and not model.is_errormap:
        raise ValueError(f"{args.result}: --map and --maps need an error-map result (model 'errormap')")

    t0 = time.perf_counter()
    errors = ReadingErrors(budget)
    u_reading = errors.std(ident.beam_lengths(x))
    std, cov, samples, extra, every = propagate(ident, x, errors, args)
    campaign_note(extra, note)
    pmap = prediction_uncertainty_map(ident, x, cov, every) if model.is_errormap else None
    elapsed = time.perf_counter() - t0
    extra.update(budget_file=args.budget or "built-in paper 000 Table 2",
                 result=args.result, campaign=args.campaign, elapsed_s=round(elapsed, 3),
                 reading_std_median_mm=float(np.median(u_reading)), reading_std_max_mm=float(np.max(u_reading)))
    if pmap is not None:
        U = args.k * pmap["u_mm"]
        extra["prediction_expanded_mm"] = {
            "k": args.k, "max": float(np.nanmax(U)), "mean": float(np.nanmean(U)),
            "points": int(np.isfinite(U[0]).sum()),
            "what": "k * sqrt(u_x^2 + u_y^2) of predicted positions on an XY grid inside the map range, "
                    "approach directions +1 and -1 (001 Fig. 14)"}
    unc = uncertainty_dict(ident, std, args.method, budget, k=args.k, samples=samples,
                           coverage=args.coverage, extra=extra)
    write_json(args.out, unc)

    u = dict(zip(ident.names, std))
    print(f"uncertainty ({args.method}) of {args.result} ({'errormap' if model.is_errormap else 'dh'}, "
          f"{len(ident.names)} parameters) on {len(data)} readings of {args.campaign}; budget {budget.name!r}"
          + (f"; {len(every)} trials, seed {args.seed}" if every is not None else "")
          + f"; {elapsed:.2f} s")
    print(f"  reading standard uncertainty (k = 1): median {1e3 * np.median(u_reading):.2f} um, "
          f"max {1e3 * np.max(u_reading):.2f} um")
    print(f"  L1: u = {1e3 * u['L1_mm']:.2f} um, L2: u = {1e3 * u['L2_mm']:.2f} um (k = 1); "
          f"U (k = {args.k:g}): {1e3 * args.k * u['L1_mm']:.2f} um, {1e3 * args.k * u['L2_mm']:.2f} um")
    if model.is_errormap:
        ranges = []
        for axis in ("J1", "J2"):
            s = np.array([v for n, v in u.items() if n.startswith(axis + "_")])
            ranges.append(f"{axis} map nodes u = {1e3 * s.min():.3f}..{1e3 * s.max():.3f} mdeg")
        print("  " + ", ".join(ranges) + " (k = 1)")
    else:
        print(f"  theta20: u = {1e3 * u['theta20_deg']:.3f} mdeg (k = 1)")
    n = ident.n_robot
    sP, sd = std[n:n + 2 * ident.n_t], std[n + 2 * ident.n_t:]
    print(f"  reflectors: u = {1e3 * sP.min():.2f}..{1e3 * sP.max():.2f} um, dead paths: u = "
          f"{1e3 * sd.min():.2f}..{1e3 * sd.max():.2f} um (k = 1)")
    if pmap is not None:
        p = extra["prediction_expanded_mm"]
        print(f"  predicted positions over the workspace map ({p['points']} points x 2 approach directions): "
              f"U (k = {args.k:g}) max {1e3 * p['max']:.2f} um, mean {1e3 * p['mean']:.2f} um")
    for line in extra.get("notes", []):
        print(f"  note: {line}")
    print(f"wrote {args.out}")
    label = "Monte Carlo" if every is not None else "linear"
    if args.map:
        plot_prediction_uncertainty_map(pmap, args.map, args.k, f"{label}, budget {budget.name}")
        print(f"wrote {args.map}")
    if args.maps:
        identified = types.SimpleNamespace(model=model, names=list(ident.names), std=std)
        plot_identified_maps(identified, None, args.maps, std=std, method=label)
        print(f"wrote {args.maps}")
    return 0


def design(args) -> int:
    """Reflector placement by the linear uncertainty method (000 §3.2.2 Remark 2, §5).

    The result's model is the truth; the plan's campaign is synthesized for the current layout (the result's
    reflectors) and for every candidate layout; the cost is the worst or mean predicted-position
    u = sqrt(u_x² + u_y²) (k = 1) over the workspace. Prints both costs and the improvement; writes DESIGN.json (mm).
    """
    from olti_drake.io.budget import budget_or_default
    from olti_drake.estimation.design import (DesignReport, LayoutEvaluator, candidate_grid, design_layout,
                                              evaluate_layout, load_regions, measured_commands, workspace_commands)
    from olti_drake.io.outputs import write_json
    from olti_drake.io.plan_io import load_plan
    from olti_drake.model.plan import bidirectional_grid
    from olti_drake.io.result import load_result

    model, P, _, _ = load_result(args.result, outside="clamp")
    plan = load_plan(args.plan) if args.plan else bidirectional_grid()
    plan_name = args.plan or "paper 000 plan (Eq. 11-12, built in)"
    budget = budget_or_default(args.budget, "scara")
    regions = load_regions(args.regions)
    n = len(P) if args.reflectors is None else args.reflectors
    if n < 3:
        raise ValueError(f"--reflectors must be >= 3 (000 §3.2.2 Remark 1), got {n}"
                         + ("" if args.reflectors is not None else f" (the result {args.result} has {len(P)})"))
    cmd = measured_commands(plan)
    if model.is_errormap:
        ws = workspace_commands(model, args.workspace_step_mm, option="--workspace-step-mm")
    else:  # a D-H model has no map range: the plan's angle ranges
        ws = workspace_commands((cmd.theta1_deg, cmd.theta2_deg), args.workspace_step_mm, model.L1_mm, model.L2_mm,
                                option="--workspace-step-mm")
    candidates = candidate_grid(regions, args.step_mm, option="--step-mm")

    t0 = time.perf_counter()
    current = evaluate_layout(LayoutEvaluator(model, plan, len(P), ws), P, budget)
    tty = sys.stderr.isatty()

    def report(start, sweep, cost):
        sys.stderr.write(f"\r  designing: start {start + 1}/{args.starts}, sweep {sweep + 1}, "
                         f"{args.criterion} u = {1e3 * cost:.2f} um   ")
        sys.stderr.flush()

    ev = LayoutEvaluator(model, plan, n, ws)
    res = design_layout(model, plan, candidates, n, budget, ws, args.criterion, seed=args.seed, starts=args.starts,
                        max_sweeps=args.max_sweeps, min_separation_mm=args.min_separation_mm,
                        clearance_mm=args.clearance_mm, base_radius_mm=args.base_radius_mm, evaluator=ev,
                        progress=report if tty else None)
    if tty:
        sys.stderr.write("\n")
    designed = evaluate_layout(ev, res.reflectors_mm, budget)
    elapsed = time.perf_counter() - t0
    doc = DesignReport(args.criterion, budget, args.budget or "built-in paper 000 Table 2", args.result, plan_name,
                       args.regions, current, designed, res, args.seed, args.starts, args.max_sweeps, args.step_mm,
                       {"min_separation_mm": args.min_separation_mm, "clearance_mm": args.clearance_mm,
                        "base_radius_mm": args.base_radius_mm}, args.workspace_step_mm, len(ws), elapsed)
    improvement = doc.improvement

    print(f"reflector layout design (000 §3.2.2 Remark 2) by linear propagation (JCGM 100), budget {budget.name!r}")
    print(f"  truth: {args.result} ({'errormap' if model.is_errormap else 'dh'}); plan: {plan_name}, "
          f"{len(cmd)} measured poses per reflector")
    print(f"  cost: predicted-position u = sqrt(u_x^2 + u_y^2) over {len(ws) // 4} workspace points x 4 approach "
          f"directions ({args.workspace_step_mm:g} mm grid inside the "
          f"{'map range' if model.is_errormap else 'plan angle ranges'})")
    print(f"  candidates: {len(res.candidates_mm)} on a {args.step_mm:g} mm grid in {len(regions)} region(s) of "
          f"{args.regions}; {int(res.feasible.sum())} feasible ({res.rejected['clearance']} within "
          f"{args.clearance_mm:g} mm of the arm, {res.rejected['base']} with a beam within {args.base_radius_mm:g} mm "
          f"of the J1 axis); separation >= {args.min_separation_mm:g} mm")
    print(f"  {'layout':22s}{'max u':>10s}{'mean u':>10s}{'max U(k=2)':>12s}   (um)")
    for label, c in (("current (result)", current), (f"designed ({n} refl.)", designed)):
        if "max_u_mm" in c:
            print(f"  {label:22s}{1e3 * c['max_u_mm']:10.2f}{1e3 * c['mean_u_mm']:10.2f}"
                  f"{1e3 * c['max_U_k2_mm']:12.2f}")
        else:
            print(f"  {label:22s}  not identifiable: {c['not_identifiable']}")
    if improvement is not None:
        print(f"  improvement ({args.criterion} u, current / designed): {improvement:.2f}x")
    for name, c in (("current", current), ("designed", designed)):
        print(f"  {name} positions (mm): " + ", ".join(f"({x:.1f}, {y:.1f})" for x, y in c["reflectors_mm"]))
    print(f"  coordinate exchange: {args.starts} start(s), seed {args.seed}, {res.evaluations} layouts evaluated, "
          f"{elapsed:.1f} s")
    write_json(args.out, doc.to_dict())
    print(f"wrote {args.out}")
    return 0


def compensate(args) -> int:
    """Commands that put the end effector on the targets by the identified model (000 Eq. 3 with Eq. 7, inverted)."""
    from olti_drake.estimation.compensation import compensate_file, write_commands, write_tables
    from olti_drake.io.result import load_result

    tables = [os.path.join(args.tables, f"{a}_compensation.csv") for a in ("J1", "J2")] if args.tables else []
    preflight([args.out] + tables, [args.result, args.targets], dirs=[args.tables] if args.tables else [], args=args)
    model, _, _, _ = load_result(args.result, outside=args.outside)
    if args.tables and not model.is_errormap:
        raise ValueError(f"{args.result}: --tables needs an error-map result (model 'errormap'), this one is 'dh'")
    comp, lines = compensate_file(model, args.targets, elbow=args.elbow)
    write_commands(comp, args.out, comments=[
        f"olti compensate: {args.result} inverted for the targets of {args.targets}; mm and degrees",
        "executed with dir1, dir2 these commands put the end effector on x_mm, y_mm by the model (000 Eq. 3, 7)"])
    c = comp.commands
    print(f"compensated {len(c)} targets ({'errormap' if model.is_errormap else 'dh'} model): "
          f"{comp.iterations} Newton iteration(s), max residual {comp.residual_mm.max():.2g} mm")
    print(f"  theta1* {c.theta1_deg.min():.4f}..{c.theta1_deg.max():.4f} deg, "
          f"theta2* {c.theta2_deg.min():.4f}..{c.theta2_deg.max():.4f} deg")
    flagged = lines[comp.needs_approach.any(axis=1)]
    if flagged.size:
        shown = ", ".join(str(n) for n in flagged[:10]) + (" ..." if flagged.size > 10 else "")
        print(f"  note: {flagged.size} target(s) reverse an axis by less than its backlash; approach them with an "
              f"overrun move in the stated direction (lines {shown})")
    print(f"wrote {args.out}")
    for path in write_tables(model, args.tables, f" from {args.result}") if args.tables else []:
        print(f"wrote {path}")
    return 0
