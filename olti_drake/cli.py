"""The ``olti`` command (shared/spec/cli.md).

Only argparse is imported at start-up, so ``olti --help`` answers at once;
each verb imports what it needs (pydrake, matplotlib) when it runs.
Bad input ends with one line ``error: ...`` on stderr and exit status 2.
"""

import argparse
import os
import sys
import time

EXIT_BAD_INPUT = 2


def _progress(enabled: bool):
    """A progress callback printing to stderr, only when stderr is a terminal."""
    if not (enabled and sys.stderr.isatty()):
        return None

    def report(fraction: float):
        sys.stderr.write(f"\r  simulating campaign {100 * fraction:5.1f} %")
        if fraction >= 1:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return report


def _refuse_overwrite(out_paths, inputs):
    """The CLI never overwrites an input file."""
    real = {os.path.realpath(p) for p in inputs if p}
    for p in out_paths:
        if os.path.realpath(p) in real:
            raise ValueError(f"{p}: output would overwrite an input file")


def _simulate(scenario_path, out_dir, seed=None, progress=True):
    from .campaign import prepare, run_campaign, write_campaign
    from .scenario import load_scenario

    scenario = load_scenario(scenario_path)
    if seed is not None:
        if seed < 0:
            raise ValueError(f"--seed must be >= 0, got {seed}")
        scenario.seed = seed
    inputs = [scenario_path]
    if scenario.budget:
        inputs.append(scenario.resolve(scenario.budget))
    if hasattr(scenario.plan, "path"):
        inputs.append(scenario.resolve(scenario.plan.path))
    _refuse_overwrite([os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json")], inputs)
    setup = prepare(scenario)
    campaign = run_campaign(setup, progress=_progress(progress))
    source = scenario_path or "embedded default (paper 000 experiment)"
    paths = write_campaign(campaign, out_dir, comments=[f"scenario: {source}; seed {scenario.seed}"])
    return setup, campaign, paths


def _summary(setup, campaign, elapsed_s: float) -> str:
    import numpy as np

    c = campaign.columns
    valid = c["valid"] > 0
    est_err = np.hypot(*(setup.reflectors_estimate_mm - setup.reflectors_mm).T)
    lines = [f"readings: {campaign.n_readings} ({int(valid.sum())} valid, {int((~valid).sum())} beam lost) "
             f"at {len(setup.plan)} plan rows x {len(setup.reflectors_mm)} reflectors "
             f"({setup.plan.n_measured} measured poses each)",
             f"simulated in {elapsed_s:.2f} s ({campaign.n_readings / max(elapsed_s, 1e-9):.0f} readings/s, "
             f"start-up included)"]
    for j, (p, e, d0) in enumerate(zip(setup.reflectors_mm, est_err, setup.dead_paths_mm)):
        sel = valid & (c["reflector"] == j)
        span = np.ptp(c["displacement_mm"][sel]) if sel.any() else float("nan")
        lines.append(f"  reflector {j}: true ({p[0]:.3f}, {p[1]:.3f}) mm, steering estimate off by "
                     f"{e:.3f} mm, dead path {d0:.3f} mm, reading span {span:.3f} mm")
    lines.append(f"  theta40: true {setup.scenario.robot.theta40_deg:.4f} deg, estimate "
                 f"{setup.theta40_estimate_deg:.4f} deg (Eq. (2) search)" if setup.search is not None else
                 f"  theta40 estimate {setup.theta40_estimate_deg:.4f} deg")
    return "\n".join(lines)


def cmd_simulate(args) -> int:
    t0 = time.perf_counter()
    setup, campaign, paths = _simulate(args.scenario, args.out, args.seed)
    print(_summary(setup, campaign, time.perf_counter() - t0))
    print(f"wrote {paths[0]} and {paths[1]}")
    return 0


def cmd_demo(args) -> int:
    """The whole story of paper 000 on the embedded default: simulate, identify, validate (§4)."""
    from .figures import write_campaign_figures
    from .result import write_result
    from .validation import campaign_data, validate_models, validation_table, write_validation_figures

    t0 = time.perf_counter()
    setup, campaign, paths = _simulate(None, args.out)
    print("paper 000 experiment, simulated (open-loop tracking interferometer on a SCARA robot)")
    print(_summary(setup, campaign, time.perf_counter() - t0))
    print(f"wrote {paths[0]} and {paths[1]}")
    r = setup.scenario.robot
    report = validate_models(campaign_data(campaign), setup.robot, (r.nominal_L1_mm, r.nominal_L2_mm),
                             seed=setup.scenario.seed)
    for (label, ident), name in zip(report.identifications.items(), ("result_dh.json", "result_errormap.json")):
        print(f"\nidentified {label} model (000 §4.2):")
        print(identification_summary(ident))
        write_result(ident, os.path.join(args.out, name))
        print(f"wrote {os.path.join(args.out, name)}")
    print()
    print(validation_table(report))
    figures = write_campaign_figures(setup, campaign, args.out) + write_validation_figures(report, args.out, setup)
    for path in figures:
        print(f"wrote {path}")
    print(f"demo done in {time.perf_counter() - t0:.1f} s")
    return 0


def _pairs(text: str, name: str, size: int):
    try:
        rows = [[float(v) for v in part.split(",")] for part in text.replace(";", " ").split()]
    except ValueError:
        rows = []
    if not rows or any(len(r) != size for r in rows):
        raise ValueError(f"{name}: expected {'x,y;x,y;...' if size == 2 else 'L1,L2'} in mm, got {text!r}")
    return rows


def identification_summary(ident) -> str:
    """Parameters ± standard uncertainty (k = 1), residual RMS, iterations, conditioning."""
    import numpy as np

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
    if ident.outliers:
        shown = ", ".join(f"line {o['line']} ({o['normalized']:+.1f} sigma)" for o in ident.outliers[:10])
        more = f" and {len(ident.outliers) - 10} more" if len(ident.outliers) > 10 else ""
        lines.append(f"  {len(ident.outliers)} suspect reading(s) beyond the outlier threshold: {shown}{more}")
    return "\n".join(lines)


def cmd_identify(args) -> int:
    from .campaign_io import load_campaign
    from .identification import IdentificationOptions, identify, parse_grid
    from .result import write_result

    _refuse_overwrite([args.out], [args.campaign])
    nominal = _pairs(args.nominal_mm, "--nominal-mm", 2)[0] if args.nominal_mm else (325.0, 225.0)
    options = IdentificationOptions(
        model=args.model, nominal_L1_mm=nominal[0], nominal_L2_mm=nominal[1],
        grid1_deg=parse_grid(args.grid1_deg, "--grid1-deg") if args.grid1_deg else None,
        grid2_deg=parse_grid(args.grid2_deg, "--grid2-deg") if args.grid2_deg else None,
        reflectors_mm=_pairs(args.reflectors_mm, "--reflectors-mm", 2) if args.reflectors_mm else None,
        fix_reflectors=args.fix_reflectors, loss=args.loss, huber_k=args.huber_k,
        outlier_threshold=args.outlier_threshold, regularize=args.regularize, solver=args.solver)
    if options.fix_reflectors and options.reflectors_mm is None:
        raise ValueError("--fix-reflectors needs --reflectors-mm")
    data = load_campaign(args.campaign)
    ident = identify(data, options)
    write_result(ident, args.out)
    print(identification_summary(ident))
    print(f"wrote {args.out}")
    return 0


def cmd_predict(args) -> int:
    from .campaign_io import load_commands
    from .csvio import write_table
    from .result import load_result

    _refuse_overwrite([args.out], [args.result, args.commands])
    from .errormap import OutsideGridError

    model, _, _, _ = load_result(args.result, outside=args.outside)
    cmd, lines = load_commands(args.commands)
    try:
        p = model.positions(cmd)
    except OutsideGridError as e:
        raise ValueError(f"{args.commands}:{lines[e.row]}: {e} -- or run with --outside clamp") from None
    cols = {"theta1_deg": cmd.theta1_deg, "theta2_deg": cmd.theta2_deg, "dir1": cmd.dir1, "dir2": cmd.dir2,
            "x_mm": p[:, 0], "y_mm": p[:, 1]}
    write_table(args.out, cols, {"dir1": "%d", "dir2": "%d", "x_mm": "%.6f", "y_mm": "%.6f"},
                comments=[f"olti predict: {args.result} applied to {args.commands}; mm and degrees"])
    print(f"predicted {len(cmd)} positions; wrote {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="olti", description="Open-loop tracking interferometer calibration (mm and degrees).")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    p = sub.add_parser("demo", help="simulate the paper-000 experiment, identify D-H and error-map models, "
                                    "compare them on unseen paths; write results and figures",
                       description="Simulate the paper-000 SCARA experiment on the embedded default "
                                   "scenario, identify the D-H and error-map models (000 §4.2), compare "
                                   "their predictions with a simulated laser tracker on paths not used in "
                                   "the identification (000 §4.3), write result_dh.json, "
                                   "result_errormap.json and figures (PNG).")
    p.add_argument("--out", default="olti_demo", help="output directory (default: olti_demo)")
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("simulate", help="run a scenario's campaign in simulation; write campaign.csv, truth.json",
                       description="Build the scenario's Drake diagram with the simulated plant, run the "
                                   "whole measurement plan, write DIR/campaign.csv and DIR/truth.json. "
                                   "Without a scenario: the paper-000 SCARA experiment (diagrams/).")
    p.add_argument("scenario", nargs="?", default=None, help="scenario YAML (default: paper 000)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("identify", help="identify the D-H or error-map model from a SCARA campaign",
                       description="Identify the model of paper 000 (D-H: Eq. 3-5; error map: Eq. 6-10) "
                                   "from a campaign CSV; print a summary; write RESULT.json.")
    p.add_argument("campaign", help="campaign CSV (formats.md)")
    p.add_argument("--model", choices=("dh", "errormap"), required=True)
    p.add_argument("--out", required=True, help="result JSON to write")
    p.add_argument("--grid1-deg", help="J1 map nodes START:STOP:STEP or a comma list (default: commanded angles)")
    p.add_argument("--grid2-deg", help="J2 map nodes (default: the distinct commanded J2 angles)")
    p.add_argument("--nominal-mm", help="nominal link lengths L1,L2 in mm, the starting point (default 325,225)")
    p.add_argument("--reflectors-mm", help="initial reflector positions 'x,y;x,y;...' mm (e.g. the Eq. (2) search)")
    p.add_argument("--fix-reflectors", action="store_true", help="treat --reflectors-mm as known")
    p.add_argument("--loss", choices=("l2", "huber"), default="l2", help="robust loss for outliers (default l2)")
    p.add_argument("--huber-k", type=float, default=3.0, help="Huber threshold in robust sigmas (default 3)")
    p.add_argument("--outlier-threshold", type=float, default=4.0,
                   help="report readings whose normalized residual exceeds this (default 4)")
    p.add_argument("--regularize", action="store_true",
                   help="regularize unidentifiable parameters (and say so) instead of stopping")
    p.add_argument("--solver", choices=("lm", "nlp"), default="lm",
                   help="lm: Levenberg-Marquardt steps as Drake programs (default); nlp: Drake NLP solver")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("predict", help="predicted actual positions for commanded angles and directions",
                       description="Apply an identified model to commands (formats.md commands.csv); write "
                                   "the commands with the predicted x_mm, y_mm.")
    p.add_argument("result", help="result JSON from olti identify")
    p.add_argument("commands", help="commands CSV: theta1_deg, theta2_deg, dir1, dir2")
    p.add_argument("--out", required=True, help="prediction CSV to write")
    p.add_argument("--outside", choices=("error", "clamp"), default="error",
                   help="commands outside the map grid: refuse (default) or hold the end values")
    p.set_defaults(func=cmd_predict)
    return parser


#: Options whose values may start with '-' (negative angles, coordinates).
_SIGNED_VALUE_OPTIONS = ("--grid1-deg", "--grid2-deg", "--reflectors-mm", "--nominal-mm")


def _join_signed_values(argv):
    """``--grid1-deg -140:60:20`` -> ``--grid1-deg=-140:60:20`` (argparse would take it for an option)."""
    out, it = [], iter(argv)
    for a in it:
        if a in _SIGNED_VALUE_OPTIONS:
            nxt = next(it, None)
            out.append(a if nxt is None else f"{a}={nxt}")
        else:
            out.append(a)
    return out


def main(argv=None) -> int:
    args = build_parser().parse_args(_join_signed_values(sys.argv[1:] if argv is None else argv))
    from .csvio import InputError

    try:
        return args.func(args)
    except (InputError, ValueError, FileNotFoundError) as e:
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
