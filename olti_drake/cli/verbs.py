"""The ``olti`` command (README.md "Command line"; ``olti VERB --help``).

Only argparse is imported at start-up, so ``olti --help`` answers at once;
each verb imports what it needs (pydrake, matplotlib) when it runs.
Bad input ends with one line ``error: ...`` on stderr and exit status 2.
"""

import argparse
import shlex
import os
import sys
import signal
import time

import olti_drake.cli.args as cliargs

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


def _check_outputs(args, files=(), inputs=(), measurements=(), dirs=(), create_dirs=False):
    """Every output of a verb, checked before its work (olti_drake.io.outputs.preflight): never an input,
    never a measurement, an existing result only with --force, a directory that can take it."""
    from olti_drake.io.outputs import preflight

    preflight(files, inputs, force=getattr(args, "force", False), measurements=measurements, dirs=dirs,
              create_dirs=create_dirs)


def _simulate(args, scenario_path, out_dir, seed=None, progress=True, view=None, results=()):
    """Simulate the scenario's campaign into ``out_dir`` (campaign.csv, truth.json: measurements, never
    replaced); ``results``: the caller's other outputs, checked with them before the simulation;
    ``view()``: (extend, realtime rate) of a live view, started only once the outputs are known good."""
    from olti_drake.hardware.station import AddStation
    from olti_drake.sim.campaign import prepare, run_campaign, write_campaign
    from olti_drake.sim.scenario import Hardware, load_scenario

    scenario = load_scenario(scenario_path, getattr(args, "scenario_name", None), getattr(args, "scenario_text", None))
    if isinstance(scenario.station, Hardware):
        raise ValueError(f"scenario {scenario_path}: station !Hardware: olti {args.verb} runs the simulated "
                         f"station; drive the hardware with: olti run {scenario_path} --out DIR")
    if seed is not None:  # checked by argparse (cliargs.seed)
        scenario.seed = seed
    inputs = [scenario_path]
    if scenario.budget:
        inputs.append(scenario.resolve(scenario.budget))
    if hasattr(scenario.plan, "path"):
        inputs.append(scenario.resolve(scenario.plan.path))
    _check_outputs(args, [os.path.join(out_dir, n) for n in results], inputs,
                   [os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json")], [out_dir], create_dirs=True)
    extend, realtime_rate = view() if view else (None, 0.0)
    setup = prepare(scenario)
    campaign = run_campaign(setup, progress=_progress(progress), extend=extend, realtime_rate=realtime_rate,
                            station_factory=AddStation)
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


def _meshcat_view(args):
    """(extend, realtime rate) of the --meshcat options: the live view's systems, or none."""
    extend, rate = None, args.realtime_rate  # >= 0, checked by argparse (cliargs.nonnegative)
    if args.meshcat:
        from olti_drake.sim.meshcat_view import campaign_view, start_meshcat

        meshcat = start_meshcat(args.meshcat_port)
        print(f"meshcat: live view at {meshcat.web_url()}", flush=True)
        extend, rate = campaign_view(meshcat, error_scale=args.error_scale), 20.0 if rate is None else rate
    return extend, rate or 0.0


def _serial_meshcat_view(args):
    """(extend, realtime rate) of the --meshcat options for a six-axis scenario, or none."""
    if not args.meshcat:
        return None, (args.realtime_rate or 0.0)
    from olti_drake.sim.serial_view import add_serial_view, start_meshcat

    meshcat = start_meshcat(args.meshcat_port)
    print(f"meshcat: live view at {meshcat.web_url()}", flush=True)
    rate = 20.0 if args.realtime_rate is None else args.realtime_rate
    return (lambda builder, setup, station, seq: add_serial_view(builder, meshcat, setup, station, seq,
                                                                 args.error_scale)), rate


def _add_meshcat_options(p):
    p.add_argument("--meshcat", action="store_true",
                   help="live 3D view in the browser (prints the URL): arm, beam, reflectors, error vectors")
    p.add_argument("--meshcat-port", type=cliargs.port, default=None,
                   help="Meshcat port (default: first free from 7000)")
    p.add_argument("--realtime-rate", type=cliargs.nonnegative, default=None,
                   help="simulated/wall time, to watch (default: 20 with --meshcat, else as fast as possible)")
    p.add_argument("--error-scale", type=cliargs.real(0, 1e6, lo_open=True), default=500.0,
                   help="magnification of the error vectors in the view (default 500, 000 Fig. 11 style)")


def _add_scenario_options(p) -> None:
    p.add_argument("--scenario", dest="scenario_name", metavar="NAME", default=None,
                   help="the scenario named NAME in a file of named scenarios (e.g. diagrams/scenarios.yaml)")
    p.add_argument("--scenario-text", metavar="YAML", default=None,
                   help="YAML overrides over the scenario, e.g. '{seed: 3, station: !Emulated {drop: 0.01}}'")


def cmd_simulate(args) -> int:
    from olti_drake.sim.serial_scenario import scenario_function, scenario_kind

    kind = scenario_kind(args.scenario, args.scenario_name)  # (sim.serial_scenario: the one place)
    if kind == "serial":  # a six-axis scenario (it has a `scheme`)
        from olti_drake.sim.serial_station import simulate_serial_command
        print(simulate_serial_command(args.scenario, args.scenario_name, args.scenario_text, args.out, args.seed,
                                      _progress(True), lambda: _serial_meshcat_view(args)))
        if args.meshcat and sys.stdin.isatty():
            input("press Enter to close the Meshcat view: ")
        return 0
    simulate = scenario_function(kind, "simulate")  # (a machine tool's: sim.serial_scenario.SCENARIO_TYPES)
    if simulate is not None:
        print(simulate(args.scenario, args.scenario_name, args.scenario_text, args.out, args.seed, args.meshcat))
        return 0
    t0 = time.perf_counter()
    setup, campaign, paths = _simulate(args, args.scenario, args.out, args.seed, view=lambda: _meshcat_view(args))
    print(_summary(setup, campaign, time.perf_counter() - t0))
    print(f"wrote {paths[0]} and {paths[1]}")
    if args.meshcat and sys.stdin.isatty():
        input("press Enter to close the Meshcat view: ")
    return 0


def cmd_plan(args) -> int:
    """The plan of a six-axis scenario and its predicted quality before any measurement."""
    from olti_drake.sim.serial_scenario import scenario_kind
    from olti_drake.sim.serial_station import plan_command

    if scenario_kind(args.scenario, args.scenario_name) != "serial":
        raise ValueError(f"{args.scenario}: olti plan reports six-axis (floor tracer) scenarios; the SCARA plan is "
                         f"data/plan_paper000.yaml (olti design evaluates it)")
    if args.out:
        _check_outputs(args, [args.out], [args.scenario])
    print(plan_command(args.scenario, args.scenario_name, args.scenario_text, args.out))
    return 0


def cmd_demo(args) -> int:
    """The whole story of paper 000 on the embedded default: simulate, identify, validate (§4)."""
    if args.robot == "six_axis":  # the six-axis story (olti_drake/report/six_axis_demo.py)
        from olti_drake.report.six_axis_demo import run_six_axis_demo
        print("\n".join(run_six_axis_demo(args.out, args.force)))
        return 0
    from olti_drake.cli.scara_verbs import identification_summary
    from olti_drake.report.figures import CAMPAIGN_FIGURES, write_campaign_figures
    from olti_drake.io.result import write_result
    from olti_drake.report.validation import (VALIDATION_FIGURES, campaign_data, validate_models, validation_table,
                             write_validation_figures)

    t0 = time.perf_counter()
    results = ("result_dh.json", "result_errormap.json") + CAMPAIGN_FIGURES + VALIDATION_FIGURES
    setup, campaign, paths = _simulate(args, None, args.out, results=results)
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


def cmd_identify(args) -> int:
    """campaign CSV -> calibration_problem -> fit -> result document -> written (olti_drake.cli.identify)."""
    from olti_drake.cli.identify import identify

    if getattr(args, "cv", None) is not None:  # the validation printed first (olti_drake.cli.validate)
        from olti_drake.cli.validate import cv_before_identify

        cv_before_identify(args)
    return identify(args, args.model)


def cmd_validate(args) -> int:
    """K-fold cross-validation by pose of candidate models (olti_drake.cli.validate; serial robots: cli.kinds)."""
    from olti_drake.cli.kinds import campaign_handler

    return campaign_handler("validate", args)(args)


def cmd_import_points(args) -> int:
    """A tracker export and a joint log as a point campaign (olti_drake.cli.import_points)."""
    from olti_drake.cli.import_points import import_points

    return import_points(args)


def cmd_multilaterate(args) -> int:
    """001 Eq. 2-6 on a 2D or 3D machine-tool campaign: the identify route with model multilateration."""
    from olti_drake.cli.identify import identify

    return identify(args, "multilateration")


def _add_force(p):
    """--force: the verbs that write results (never a measurement nor an input: olti_drake.io.outputs)."""
    p.add_argument("--force", action="store_true",
                   help="replace existing result files (a campaign, a run log or an input is never replaced)")


def _add_solver_options(p):
    """The solver options every identification verb shares (calibration.SolverOptions)."""
    p.add_argument("--loss", choices=("l2", "huber", "soft_l1", "cauchy", "auto"), default=None,
                   help="loss: l2, or a robust loss for outliers (huber, soft_l1, cauchy: IRLS, scale --huber-k robust "
                        "sigmas); auto: l2 unless its residuals show outliers, then Huber at k = 1.345, said in a "
                        "note naming the outlying lines (default: auto for robots from a model file, else l2)")
    p.add_argument("--huber-k", type=cliargs.positive, default=3.0,
                   help="scale of the robust losses in robust sigmas (default 3; --loss auto's refit uses 1.345)")
    p.add_argument("--max-iterations", type=cliargs.integer(1, 1_000_000), default=None, metavar="N",
                   help="LM's iteration cap (default: fits the problem's size, max(100, 10 x the unknowns) up to "
                        "2000)")
    p.add_argument("--outlier-threshold", type=cliargs.positive, default=4.0,
                   help="report readings whose normalized residual exceeds this (default 4)")
    p.add_argument("--regularize", action="store_true",
                   help="regularize unidentifiable parameters (and say so) instead of stopping")
    p.add_argument("--solver", choices=("lm", "nlp"), default="lm",
                   help="lm: Levenberg-Marquardt steps as Drake programs (default); nlp: Drake NLP solver")


def _result_verb(args, verb: str, files=(), inputs=()) -> int:
    """A verb on a result: its kind asked once (olti_drake.cli.kinds: any result file, old ones included; the
    options that do not apply to it refused), the outputs checked, the kind's body run."""
    from olti_drake.cli.kinds import handler, result_kind_of

    kind = result_kind_of(args, verb)
    if files:
        _check_outputs(args, files, inputs)
    return handler(verb, kind)(args)


def cmd_predict(args) -> int:
    return _result_verb(args, "predict", [args.out], [args.result, args.commands])


def cmd_uncertainty(args) -> int:
    """Uncertainty of an identified result from its campaign and a budget (000 §5; 001 §4.4).

    linear: JCGM 100 propagation (std = sqrt(diag(cov))); mc: JCGM 101 Monte
    Carlo (sample std, ddof = 1). Writes the formats.md ``uncertainty`` object
    (k = 1, plus ``expanded`` with --k); mm and degrees.
    """
    from olti_drake.cli.kinds import MC_TRIALS, handler, result_kind_of
    from olti_drake.estimation.trials import check_backend
    from olti_drake.estimation.uncertainty import round_trials

    kind = result_kind_of(args, "uncertainty")
    args.trials = MC_TRIALS.get(kind, 1000) if args.trials is None else args.trials
    _check_outputs(args, [args.out, args.map, args.maps], [args.result, args.campaign, args.budget])
    check_backend(args.backend, args.scheduler, args.workers)  # before any work: a missing package, one line
    if args.max_trials < 2 * round_trials(args.coverage):  # a bound between two options: not argparse's
        raise ValueError(f"--max-trials must be >= {2 * round_trials(args.coverage)} (two adaptive rounds of "
                         f"--coverage {args.coverage:g}), got {args.max_trials}")
    return handler("uncertainty", kind)(args)


def cmd_design(args) -> int:
    """Reflector placement by the linear uncertainty method (000 §3.2.2 Remark 2, §5).

    The result's model is the truth; the plan's campaign is synthesized for the
    current layout (the result's reflectors) and for every candidate layout;
    the cost is the worst or mean predicted-position u = sqrt(u_x² + u_y²)
    (k = 1) over the workspace. Prints both costs and the improvement; writes
    DESIGN.json (mm).
    """
    from olti_drake.estimation.trials import check_backend

    check_backend(args.backend, args.scheduler, args.workers)  # before any work: a missing package, one line
    # --step-mm not given: 50 mm for the robots; a machine tool in 3D derives its own from the regions' size.
    args.step_mm_default = args.step_mm is None
    if args.step_mm is None:
        args.step_mm = 50.0
    return _result_verb(args, "design", [args.out], [args.result, args.plan, args.regions, args.budget])


def cmd_diagrams(args) -> int:
    """Render the simulated, emulated and hardware campaign diagrams (SVG + wiring files)."""
    from olti_drake.report.diagram_pictures import SCENARIOS, write_pictures
    from olti_drake.io.resources import source_tree_dir

    out = args.out or source_tree_dir("diagrams")
    if out is None:
        raise ValueError("olti diagrams: give --out DIR (the default, diagrams/ of a source checkout, is not "
                         "there: the package is installed)")
    _check_outputs(args, [os.path.join(out, n + ext) for n in SCENARIOS for ext in (".svg", ".wiring.txt")],
                   dirs=[out], create_dirs=True)
    for path in write_pictures(out):
        print(f"wrote {path}")
    return 0


def cmd_report(args) -> int:
    """The calibration report: DIR/report.html, self-contained (figures embedded, also written as PNG)."""
    from olti_drake.report.html import write_report

    t0 = time.perf_counter()
    paths = write_report(args.result, args.out, args.uncertainty, args.campaign, args.truth, date=args.date,
                         force=args.force, iso9283_path=args.iso9283, tolerances=args.tolerance)
    for path in paths:
        print(f"wrote {path}")
    html_path = paths[-1]
    print(f"report {html_path}: {os.path.getsize(html_path) / 1e6:.2f} MB, self-contained, "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


def cmd_compensate(args) -> int:
    """Commands that put the end effector on the targets by the identified model (000 Eq. 3 with Eq. 7, inverted);
    each kind's body checks its outputs (the tables it writes depend on the result)."""
    return _result_verb(args, "compensate")


def _stop_on_signals():
    """(should_stop, restore): a flag that SIGINT/SIGTERM set (a second Ctrl-C stops at once) and a
    function that puts the previous handlers back. The runner polls the flag between readings."""
    import signal

    stop = {"signal": None}

    def on_signal(signum, frame):
        if stop["signal"] is not None:
            raise KeyboardInterrupt     # a second Ctrl-C: stop at once
        stop["signal"] = signal.Signals(signum).name

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    return (lambda: stop["signal"]), (lambda: [signal.signal(s, h) for s, h in old.items()])


def cmd_tracker_emulator(args) -> int:
    """The emScon tracker emulator until Ctrl-C (olti_drake.cli.tracker_emulator)."""
    from olti_drake.cli.tracker_emulator import tracker_emulator

    return tracker_emulator(args)


def cmd_run(args) -> int:
    from olti_drake.hardware.station import StationError
    from olti_drake.hardware.runner import run

    import logging

    resume_hint = f"olti run {args.scenario} --out {args.out} --resume"
    # The emulator's notes on injected faults are for the emulator's own log, not this command's stderr.
    logging.getLogger("olti_drake.hardware.emulator").addHandler(logging.NullHandler())
    nl = "\n" if sys.stderr.isatty() else ""

    def progress(done, planned):
        if sys.stderr.isatty():
            sys.stderr.write(f"\r  readings on disk {done}/{planned}")
            sys.stderr.flush()

    from olti_drake.hardware.runner import load_run_scenario

    for flag, value in (("--scenario", args.scenario_name), ("--scenario-text", args.scenario_text)):
        if value:
            resume_hint += f" {flag} {shlex.quote(value)}"
    scenario = load_run_scenario(args.scenario, args.scenario_name, args.scenario_text)
    from olti_drake.cli.kinds import refuse_inapplicable
    from olti_drake.sim.serial_scenario import scenario_kind

    refuse_inapplicable("run", scenario_kind(scenario), args)  # --meshcat draws the SCARA's arm
    should_stop, restore = _stop_on_signals()
    try:
        extend, rate = _meshcat_view(args)
        s = run(scenario, args.out, resume=args.resume, fsync=not args.no_fsync, progress=progress,
                extend=extend, realtime_rate=rate, should_stop=should_stop)
    except StationError as e:
        print(f"{nl}error: {' '.join(str(e).split())}; every reading taken is on disk; after fixing it continue "
              f"with: {resume_hint}", file=sys.stderr)
        return 3
    finally:
        restore()
    if s.stopped:
        print(f"{nl}error: interrupted by {s.stopped}: {s.on_disk} of {s.planned} readings on disk in "
              f"{s.log_path}; continue with: {resume_hint}", file=sys.stderr)
        return 130
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    if s.taken == 0 and s.complete:
        print(f"{args.out}: the campaign is already complete ({s.on_disk} of {s.planned} readings)")
        return 0
    print(f"session {s.session}: {s.taken} readings taken ({s.invalid} invalid) from step {s.start_step} in "
          f"{s.elapsed_s:.2f} s; {s.on_disk} of {s.planned} planned readings in "
          f"{s.log_path}" + ("" if s.complete else " (incomplete)"))
    return 0 if s.complete else 1


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is the one line ``error: olti VERB: ...`` (exit 2), as every bad input."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"error: {self.prog}: {' '.join(message.split())} (see {self.prog} --help)\n")


#: Most Monte Carlo trials an option takes: 10^8 trials of the paper problem would run for days (the library
#: refuses below that when the samples would not fit in memory: estimation.uncertainty.MAX_SAMPLE_BYTES).
MAX_TRIALS_OPTION = 100_000_000


def _add_where_options(p, what: str, default: str) -> None:
    """--workers, --backend, --scheduler: where ``what`` run (estimation.trials.run_trials; docs/trials.md)."""
    p.add_argument("--workers", type=cliargs.workers, default=None,
                   help=f"worker processes for {what} (default: {default}; with --backend dask the local cluster's; "
                        f"results do not depend on it)")
    p.add_argument("--backend", choices=("loky", "dask", "ray"), default="loky",
                   help=f"where {what} run (joblib): loky, worker processes here (default); dask, a Dask cluster "
                        f"(local, or --scheduler); ray, the Ray cluster of RAY_ADDRESS (docs/trials.md)")
    p.add_argument("--scheduler", metavar="ADDR",
                   help="with --backend dask: the scheduler of a running cluster, e.g. tcp://10.0.0.5:8786 (default: "
                        "a local cluster of --workers processes)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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
    p.add_argument("--robot", choices=("scara", "six_axis"), default="scara",
                   help="scara: the paper-000 experiment (default); six_axis: the UR5-class campaign of "
                        "diagrams/six_axis.yaml (floor tracers), identified and validated the same way")
    _add_force(p)
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("simulate", help="run a scenario's campaign in simulation; write campaign.csv, truth.json",
                       description="Build the scenario's Drake diagram with the simulated plant, run the "
                                   "whole measurement plan, write DIR/campaign.csv and DIR/truth.json. "
                                   "Without a scenario: the paper-000 SCARA experiment (diagrams/).")
    p.add_argument("scenario", nargs="?", default=None, help="scenario YAML (default: paper 000)")
    _add_scenario_options(p)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=cliargs.seed, default=None, help="override the scenario's seed")
    _add_meshcat_options(p)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("plan", help="a six-axis scenario's plan and its predicted quality, before any measurement",
                       description="Generate the plan of a six-axis (floor tracer) scenario and report, per joint, "
                                   "the map nodes covered in each approach direction, and the plan's predicted "
                                   "identifiability and node uncertainties by the linear method (the scenario's "
                                   "budget and station estimates) -- before running it. mm and degrees.")
    p.add_argument("scenario", help="six-axis scenario YAML (e.g. diagrams/six_axis.yaml)")
    _add_scenario_options(p)
    p.add_argument("--out", default=None, help="plan CSV to write (poses in order, joints, directions, stations)")
    _add_force(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("identify", help="identify the D-H or error-map model from a SCARA or serial-robot campaign",
                       description="Identify the model of paper 000 (D-H: Eq. 3-5; error map: Eq. 6-10) "
                                   "from a campaign CSV; print a summary; write RESULT.json. With --robot FILE "
                                   "--tool-frame NAME: any serial robot Drake loads (URDF/SDFormat; ur5 and scara "
                                   "are shipped), from a distance or tracker-point campaign with theta1_deg .. "
                                   "thetaN_deg (docs/serial_robots.md).")
    p.add_argument("campaign", help="campaign CSV (formats.md)")
    p.add_argument("--model", choices=("dh", "errormap", "volumetric", "geometric"), required=True,
                   help="volumetric: the 21 ISO 230-1 error motions of a 3-axis machine from a 3D machine campaign "
                        "(docs/machine_3d.md); with --machine: geometric (the rotary axes' location errors and tool "
                        "offsets) or errormap (plus their error motions, docs/five_axis.md)")
    p.add_argument("--out", required=True, help="result JSON to write")
    p.add_argument("--grid1-deg", help="J1 map nodes START:STOP:STEP or a comma list (default: commanded angles)")
    p.add_argument("--grid2-deg", help="J2 map nodes (default: the distinct commanded J2 angles)")
    p.add_argument("--nominal-mm", type=cliargs.pairs_mm(2, positive=True),
                   help="nominal link lengths L1,L2 in mm, the starting point (default 325,225)")
    p.add_argument("--reflectors-mm", type=cliargs.pairs_mm(2),
                   help="initial reflector positions 'x,y;x,y;...' mm (e.g. the Eq. (2) search)")
    p.add_argument("--fix-reflectors", action="store_true", help="treat --reflectors-mm as known")
    p.add_argument("--tool-offsets-mm", type=cliargs.pairs_mm(3),
                   help="volumetric: the offset of every tool index 'x,y,z;x,y,z;...' mm from the spindle reference "
                        "point (tool 0's taken as given, the others' estimated; default 0,0,0 for a 1-tool campaign)")
    p.add_argument("--knot-spacing-mm", type=cliargs.length_mm,
                   help="volumetric: largest B-spline knot interval of the error motions (default: up to 8 intervals "
                        "per axis, fewer when the campaign has few distinct positions); with --machine: the linear "
                        "axes' knot interval (default: 6 intervals over the longest linear travel)")
    p.add_argument("--topology", choices=("serial", "table-xy", "table-yx", "table-y"), default="serial",
                   help="volumetric: serial X-Y-Z (default); table-xy: table carries X on Y, column Z; table-yx: "
                        "table carries Y on X, column Z; table-y: table carries Y, column X, ram Z on X (the A/C "
                        "trunnion's linear axes)")
    p.add_argument("--pitch-mm", type=cliargs.length_mm,
                   help="volumetric: the motion values and their uncertainties every S mm (default 10)")
    p.add_argument("--budget", help="budget YAML whose predicted reading uncertainty the residual RMS is checked "
                                    "against (warning above 3 x; default: 000 Table 2)")
    p.add_argument("--robot", help="any serial robot: a URDF/SDFormat model file, or a shipped model (ur5, scara); "
                                   "the campaign then has theta1_deg..thetaN_deg (docs/serial_robots.md)")
    p.add_argument("--tool-frame", help="with --robot: the frame carrying the tool point (e.g. tool0); with --machine: "
                                        "the tool frame on the spindle (default tool)")
    p.add_argument("--machine", help="a five-axis machine tool: its URDF/SDFormat model file (prismatic X, Y, Z and "
                                     "revolute A, B, C joints named by their letters; formats.md, Five-axis machine "
                                     "tools); the campaign then has x/y/z_cmd_mm and <letter>_cmd_deg")
    p.add_argument("--workpiece-frame", help="with --machine: the workpiece frame on the table (default workpiece)")
    p.add_argument("--linear", metavar="auto|identify|perfect|RESULT.json",
                   help="with --machine: the linear axes' 18 error motions and 3 squareness errors: identify (with "
                        "the rotary axes), perfect (none), from an earlier volumetric result (olti identify --model "
                        "volumetric), held fixed, not estimated; auto (default): identify for distance or tracker "
                        "readings, perfect for an R-test campaign alone (docs/five_axis.md)")
    p.add_argument("--tool-offset-mm", type=cliargs.pairs_mm(3),
                   help="with --robot: nominal tool point x,y,z in the tool frame, mm (the start; default 0,0,0)")
    p.add_argument("--grid-step-deg", type=cliargs.real(0, 360, lo_open=True), default=None,
                   help="with --robot: error-map nodes every S degrees over each joint's commanded range (default "
                        "7.5 with the smoothness prior, 15 with --smoothing off)")
    p.add_argument("--compliance", action="store_true",
                   help="with --robot: joint compliance under gravity, c_i deg/(N m) times the gravity torque from the "
                        "model file's masses (joints with too little torque variation are dropped by name)")
    p.add_argument("--drift", action="store_true",
                   help="with --robot: linear drift of each station's dead path in time, mm/h (distance campaigns "
                        "with a time_s column)")
    p.add_argument("--smoothing", type=cliargs.smoothing, default=None,
                   help="the smoothness prior of error maps (--robot errormap: second differences of each direction "
                        "and of the backlash; default auto) and of volumetric error motions (the integral of the "
                        "squared second derivative, finer knots; default off): auto (its weight by restricted "
                        "maximum likelihood, stated in the result), off, or the weight itself (as a result's "
                        "'smoothing.weight' states it)")
    p.add_argument("--cv", type=cliargs.integer(2), default=None, metavar="K",
                   help="with --robot: first print a K-fold cross-validation by pose of the candidate models "
                        "(olti validate's defaults and the model asked), then identify --model as asked")
    _add_solver_options(p)
    _add_force(p)
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("validate", help="K-fold cross-validation by pose of candidate models; the recommended one",
                       description="Cross-validate candidate models of a serial robot (--robot FILE --tool-frame "
                                   "NAME) on a distance or tracker campaign: K folds of its poses (the rows of a pose "
                                   "together, folds seeded), each model identified on the other folds with the "
                                   "identify options given and its held-out RMS (mm) with the spread over the folds; "
                                   "the recommended model by the one-standard-error rule; write CV.json. mm, deg.")
    p.add_argument("campaign", help="campaign CSV of an N-joint robot (formats.md)")
    p.add_argument("--out", required=True, help="CV JSON to write")
    p.add_argument("--folds", type=cliargs.integer(2), default=5, metavar="K",
                   help="number of folds, 2 .. the number of poses (default 5)")
    p.add_argument("--models", default=None,
                   help="candidates, comma list: dh, errormap (at --grid-step-deg), errormap:STEP_DEG, compliance, "
                        "drift, or BASE+compliance / BASE+drift (default: dh,errormap:30,errormap:15,errormap:7.5 "
                        "and dh+compliance, dh+drift where they apply)")
    p.add_argument("--seed", type=cliargs.seed, default=0, help="seed of the fold assignment (default 0)")
    p.add_argument("--robot", help="a URDF/SDFormat model file, or a shipped model (ur5, scara)")
    p.add_argument("--tool-frame", help="the frame carrying the tool point (e.g. tool0)")
    p.add_argument("--tool-offset-mm", type=cliargs.pairs_mm(3),
                   help="nominal tool point x,y,z in the tool frame, mm (the start; default 0,0,0)")
    p.add_argument("--grid-step-deg", type=cliargs.real(0, 360, lo_open=True), default=None,
                   help="the grid step of the candidate 'errormap' without a step (default 15)")
    p.add_argument("--compliance", action="store_true", help="every candidate with joint compliance under gravity")
    p.add_argument("--drift", action="store_true", help="every candidate with the stations' dead-path drift (time_s)")
    p.add_argument("--smoothing", type=cliargs.smoothing, default=None,
                   help="the error maps' roughness prior, as olti identify's: auto (default), off or a weight")
    p.add_argument("--budget", help="budget YAML (as olti identify's)")
    _add_solver_options(p)
    _add_force(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("predict", help="predicted actual positions for commanded angles and directions",
                       description="Apply an identified model to commands (formats.md commands.csv); write "
                                   "the commands with the predicted x_mm, y_mm. A serial robot's result: "
                                   "theta1_deg .. thetaN_deg [, dir1 .. dirN] in, x_mm, y_mm, z_mm out; a distance "
                                   "campaign given as FILE also gets predicted_displacement_mm (cross-validation).")
    p.add_argument("result", help="result JSON from olti identify")
    p.add_argument("commands", help="commands CSV: theta1_deg, theta2_deg[, dir1, dir2]")
    p.add_argument("--out", required=True, help="prediction CSV to write")
    p.add_argument("--outside", choices=("error", "clamp"), default="error",
                   help="commands outside the map grid: refuse (default) or hold the end values")
    _add_force(p)
    p.set_defaults(func=cmd_predict)

    p = sub.add_parser("multilaterate", help="paper-001 self-calibrating multilateration of a machine-tool campaign",
                       description="Identify target positions, station positions and dead paths from a machine-tool "
                                   "campaign (001 Eq. 2-6, 2D, or 3D when it has z_cmd_mm) with the frame fixed by an explicit gauge; write "
                                   "RESULT.json (formats.md). mm.")
    p.add_argument("campaign", help="machine-tool campaign CSV (formats.md)")
    p.add_argument("--out", required=True, help="result JSON to write")
    from olti_drake.cli.machine_verbs import add_multilaterate_options

    add_multilaterate_options(p, cliargs)
    p.add_argument("--budget", help="budget YAML for the standard uncertainties (default: 001 Table 4); "
                                    "'residuals' propagates the residual variance instead")
    _add_solver_options(p)
    _add_force(p)
    p.set_defaults(func=cmd_multilaterate)

    p = sub.add_parser("uncertainty", help="standard uncertainties of an identified result from a budget "
                                           "(linear or Monte Carlo)",
                       description="Propagate an uncertainty budget (default: 000 Table 2) through the "
                                   "identification of RESULT.json on CAMPAIGN.csv: linear (JCGM 100) or Monte "
                                   "Carlo (JCGM 101, 000 §5). Writes the formats.md 'uncertainty' object: "
                                   "standard uncertainties (k = 1) with the result's keys and shapes, plus "
                                   "'expanded' (k = --k); mm and degrees.")
    p.add_argument("result", help="result JSON from olti identify")
    p.add_argument("campaign", help="the campaign CSV the result was identified from")
    p.add_argument("--method", choices=("mc", "linear"), required=True,
                   help="mc: Monte Carlo (JCGM 101); linear: Jacobian propagation (JCGM 100)")
    p.add_argument("--budget", help="budget YAML (e.g. data/budget_paper001.yaml; default: 000 Table 2)")
    p.add_argument("--trials", type=cliargs.integer(2, MAX_TRIALS_OPTION), default=None,
                   help="Monte Carlo trials (default 1000, five-axis results 200; ignored with --adaptive; the "
                        "samples must fit in 4 GiB)")
    p.add_argument("--k", type=cliargs.coverage_factor, default=2.0, help="coverage factor of 'expanded' (default 2)")
    p.add_argument("--coverage", type=cliargs.probability, default=0.95,
                   help="probability of the Monte Carlo coverage intervals (default 0.95)")
    p.add_argument("--seed", type=cliargs.seed, default=0, help="Monte Carlo seed (default 0)")
    _add_where_options(p, "the Monte Carlo trials", "up to 2 cores from 1000 trials on, or --adaptive")
    p.add_argument("--adaptive", action="store_true",
                   help="Monte Carlo until every estimate, standard uncertainty and coverage-interval endpoint "
                        "is stable to 2 significant digits of u (JCGM 101 §7.9), at most --max-trials")
    p.add_argument("--max-trials", type=cliargs.integer(2, MAX_TRIALS_OPTION), default=50_000,
                   help="cap on the trials of --adaptive (default 50000: a few minutes on the paper problem); "
                        "ending there unstable is reported as converged: false")
    p.add_argument("--map", help="PNG: U(k) of predicted positions over the workspace (001 Fig. 14 style)")
    p.add_argument("--workspace-poses", type=cliargs.integer(10, 100_000), default=400,
                   help="robots from a model file: seeded workspace poses where the predicted tool point's u is "
                        "evaluated (default 400)")
    p.add_argument("--maps", help="PNG: identified maps with these error bars (000 Fig. 6 style)")
    p.add_argument("--out", required=True, help="uncertainty JSON to write")
    _add_force(p)
    p.set_defaults(func=cmd_uncertainty)

    p = sub.add_parser("design", help="design reflector positions that minimize the predicted-position "
                                      "uncertainty (linear method)",
                       description="Reflector (station) placement for a campaign (000 §3.2.2 Remark 2): the "
                                   "result's model is the truth, the plan is run against candidate layouts, and "
                                   "the predicted-position uncertainty over the workspace (linear propagation, "
                                   "JCGM 100, of the budget) is minimized by coordinate exchange over candidates "
                                   "on a grid inside the regions. Prints the current and the designed layout's "
                                   "costs; writes DESIGN.json. mm and degrees.")
    p.add_argument("result", help="result JSON from olti identify (its model is the truth, its reflectors the "
                                  "current layout)")
    p.add_argument("--plan", help="plan CSV or YAML (default: the paper 000 plan, Eq. 11-12)")
    p.add_argument("--regions", required=True, help="regions YAML: rectangles {x_mm: [lo, hi], y_mm: [lo, hi]} "
                                                    "(e.g. data/regions_paper000.yaml); 3D boxes with z_mm for "
                                                    "robots from a model file and machine tools in 3D; five-axis "
                                                    "results: each box with frame: base (stations on the bed), "
                                                    "workpiece (stations riding on the table) or nest (R-test "
                                                    "nests; docs/five_axis.md)")
    p.add_argument("--reflectors", "--stations", type=cliargs.integer(3, 1000), default=None,
                   help="number of reflectors (robots) or stations (machine tool in 3D) to place (default: as many "
                        "as the result has)")
    p.add_argument("--criterion", choices=("max", "mean"), default="max",
                   help="minimize the worst (default) or the mean predicted-position u over the workspace")
    p.add_argument("--budget", help="budget YAML (default: 000 Table 2)")
    p.add_argument("--step-mm", type=cliargs.length_mm, default=None,
                   help="candidate grid step in the regions (default 50; machine tools in 3D: from the regions' "
                        "size, about 100 candidates)")
    p.add_argument("--workspace-step-mm", type=cliargs.length_mm, default=50.0,
                   help="step of the workspace XY grid the cost is evaluated on (default 50; SCARA)")
    p.add_argument("--workspace-poses", type=cliargs.integer(10, 100_000), default=300,
                   help="seeded workspace poses the cost is evaluated at (default 300; robots from a model file)")
    p.add_argument("--seed", type=cliargs.seed, default=0, help="seed of the random starts (default 0)")
    p.add_argument("--starts", type=cliargs.count, default=3, help="random starts (default 3)")
    p.add_argument("--max-sweeps", type=cliargs.count, default=5, help="exchange sweeps per start at most (default 5)")
    p.add_argument("--min-separation-mm", type=cliargs.distance_mm, default=100.0,
                   help="minimum distance between reflectors (default 100)")
    p.add_argument("--clearance-mm", type=cliargs.distance_mm, default=50.0,
                   help="minimum distance of a reflector from every end-effector position (default 50)")
    p.add_argument("--base-radius-mm", type=cliargs.distance_mm, default=40.0,
                   help="beams must pass at least this far from the J1 axis (robot base; default 40, 0: off)")
    _add_where_options(p, "the random starts (robots from a model file, machine tools)", "this process")
    p.add_argument("--out", required=True, help="design JSON to write")
    _add_force(p)
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("diagrams", help="draw the simulated, emulated and hardware campaign diagrams (Graphviz SVG)",
                       description="Build the campaign diagram of diagrams/paper000_scara.yaml, "
                                   "paper000_emulated.yaml and paper000_hardware.yaml (the hardware station on "
                                   "unopened ports, the emulator started and stopped) and write NAME.svg "
                                   "(Graphviz dot) and NAME.wiring.txt (sorted 'src.port -> dst.port' lines).")
    p.add_argument("--out", default=None, help="output directory (default: diagrams/ of the source checkout)")
    _add_force(p)
    p.set_defaults(func=cmd_diagrams)

    p = sub.add_parser("report", help="calibration report: one self-contained HTML page with tables and figures",
                       description="Write DIR/report.html for a result (SCARA olti-result/1 or machine-tool "
                                   "olti-multilateration/1): parameters with standard (k = 1) and expanded "
                                   "uncertainties, the identified maps with error bars (000 Fig. 6), ISO 230-2 "
                                   "style statistics per axis (B, B-bar, E, E-up, E-down, M), the predicted-position "
                                   "uncertainty map (001 Fig. 14 style, needs --campaign), residuals and, with "
                                   "--truth, validation (000 Figs. 9-11). Figures are embedded as data URIs and "
                                   "written as PNG files in DIR. mm and degrees.")
    p.add_argument("result", help="result JSON (olti identify, olti identify --model volumetric or --machine, or olti "
                                  "multilaterate)")
    p.add_argument("uncertainty", nargs="?", default=None,
                   help="uncertainty JSON of this result (olti uncertainty; default: the result's own)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--campaign", help="the campaign CSV of the result: covariance (linear), map, residuals")
    p.add_argument("--truth", help="truth.json of a simulated SCARA campaign (olti simulate): validation")
    p.add_argument("--date", help="date text for the header (the report never reads the clock)")
    p.add_argument("--iso9283", metavar="VALIDATION.csv",
                   help="robots from a model file: ISO 9283 pose accuracy (AP) and repeatability (RP) from a "
                        "tracker-point campaign with repeated cycles (each distinct command row a pose)")
    p.add_argument("--tolerance", type=cliargs.tolerances, default=None, metavar="AP_P=0.1,RP_l=0.05",
                   help="with --iso9283: a verdict line per characteristic (AP_P, RP_l in mm; AP_abc, RP_abc in deg); "
                        "five-axis results: the acceptance summary's (dispersion, modification_mm in mm; "
                        "modification_urad in urad)")
    _add_force(p)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("import-points", help="a laser tracker's point export and the robot's joint log as a point "
                                             "campaign",
                       description="Read a tracker's point export (a column-mapped CSV, or a SpatialAnalyzer-style "
                                   "ASCII point list 'Collection Group Target X Y Z') and match its points to the "
                                   "rows of the robot's joint log (theta1_deg .. thetaN_deg, optional dir1 .. dirN, "
                                   "and a name/point or time_s/timestamp column) by name (exact) or by time (nearest "
                                   "within --max-dt-s, each row used once); write the point campaign (formats.md) in "
                                   "the log's row order, mm. Unmatched points and rows are skipped and counted; "
                                   "nothing matched is refused.")
    p.add_argument("export", help="the tracker software's point export (CSV or SA-style ASCII)")
    p.add_argument("--joints", required=True, help="the robot's joint log CSV (theta1_deg .. thetaN_deg, name or "
                                                   "time_s)")
    p.add_argument("--out", required=True, help="point campaign CSV to write (never replaces a file)")
    p.add_argument("--format", choices=("auto", "csv", "sa"), default="auto",
                   help="the export's layout (default auto: SA-style when the first data line ends in three numbers)")
    p.add_argument("--columns", help="CSV column map, e.g. name=Point,x=X,y=Y,z=Z,time=Timestamp (default: name, x, "
                                     "y, z, time)")
    p.add_argument("--units", help="the export's length unit: mm, m or in (default: the SA header's, else mm)")
    p.add_argument("--match", choices=("name", "time"), default=None,
                   help="match by name (default when both files have names) or by time")
    p.add_argument("--max-dt-s", type=cliargs.positive, default=0.5,
                   help="--match time: the largest time difference of a match, s (default 0.5)")
    p.set_defaults(func=cmd_import_points)

    p = sub.add_parser("compensate", help="joint commands that put the end effector on targets by the model",
                       description="Invert the identified model (000 Eq. 3 with Eq. 7): for every target of "
                                   "TARGETS.csv (x_mm, y_mm; optional dir1, dir2) the commands theta1_deg, "
                                   "theta2_deg and approach directions that put the end effector on it. Without "
                                   "dir columns the directions follow the compensated sequence itself "
                                   "(formats.md rule). Targets beyond the reach or the map grid are refused "
                                   "with their line. A serial robot's result: TARGETS.csv has x_mm, y_mm, z_mm "
                                   "and the nominal pose theta1_deg .. thetaN_deg [, dir1 .. dirN]; the commands "
                                   "keep the nominal pose's tool orientation (damped near a singularity) and "
                                   "directions; every target is solved, one that cannot be (unreachable, "
                                   "joint_limit, outside_map) keeps its nominal command with that status, is named "
                                   "by its line on stderr, and the exit status is 3. mm and degrees.")
    p.add_argument("result", help="result JSON from olti identify (errormap or dh)")
    p.add_argument("targets", help="targets CSV: x_mm, y_mm [, dir1, dir2]")
    p.add_argument("--out", required=True, help="commands CSV to write (theta1_deg, theta2_deg, dir1, dir2, "
                                                "x_mm, y_mm)")
    p.add_argument("--tables", help="also write J1_compensation.csv and J2_compensation.csv (bidirectional "
                                    "compensation tables at the map nodes) into this directory")
    p.add_argument("--elbow", type=int, choices=(1, -1), default=1, help="+1: theta2 >= 0 (default); -1")
    p.add_argument("--urdf-out", help="serial robots (olti identify --robot): also write the robot's URDF with the "
                                      "identified joint origins and the tool point as a link")
    p.add_argument("--cartesian-out", help="serial robots: also write pre-distorted Cartesian targets (the tool "
                                           "point x_mm, y_mm, z_mm and the tool orientation rx/ry/rz_deg, fixed-axis "
                                           "XYZ, and qw..qz, by the NOMINAL model at the compensated commands) to send "
                                           "to the controller's own IK")
    p.add_argument("--ros2-control-out", help="serial robots: also write the identified joint offsets as ros2_control "
                                              "joint 'offset' parameters (YAML, radians)")
    p.add_argument("--ur-kinematics-out", help="six-joint robots from a URDF: also write the identified joint origins "
                                               "as a UR-style default_kinematics.yaml (metres, radians), with what it "
                                               "cannot hold and the residual that leaves")
    p.add_argument("--dh-out", help="serial robots: also write the identified geometry as a D-H table (CSV: "
                                    "standard D-H, Hayati's beta where consecutive axes are parallel; mm and "
                                    "degrees), with what it cannot hold and the residual that leaves")
    p.add_argument("--pitch-mm", type=cliargs.length_mm,
                   help="volumetric --tables: axis tables every S mm (default 10)")
    p.add_argument("--grid-pitch-mm", type=cliargs.length_mm,
                   help="volumetric --tables: the 3D grid of positioning-error vectors every S mm (default 50)")
    p.add_argument("--cnc", choices=("siemens", "fanuc", "heidenhain", "linuxcnc", "csv"),
                   help="five-axis results (olti identify --machine): also write what this controller loads into "
                        "--tables DIR (docs/cnc_exports.md), with what the format cannot hold and its residual. "
                        "TARGETS.csv then has x_mm, y_mm, z_mm and the tool direction i, j, k or the nominal pose "
                        "<letter>_cmd_deg (docs/five_axis.md)")
    p.add_argument("--outside", choices=("error", "clamp"), default="error",
                   help="commands outside the map grid: refuse the target (default) or hold the end values")
    _add_force(p)
    p.set_defaults(func=cmd_compensate)
    p = sub.add_parser("run", help="run a scenario's campaign on its station (simulated, emulated or hardware), "
                                   "writing every reading to disk as it arrives; --resume continues",
                       description="Run the scenario's measurement plan on the station the scenario names "
                                   "(station: !Simulated, !Emulated or !Hardware). Every reading is appended to "
                                   "DIR/campaign.csv (formats.md columns plus step, session, raw status, "
                                   "attempts, time) and flushed to disk as it arrives; events (zeroings, "
                                   "re-reads, alarms) go to DIR/events.jsonl. After Ctrl-C, kill -9 or a lost "
                                   "line, --resume continues from the first reading not on disk: none lost, "
                                   "none duplicated (docs/runner.md). Exit 0 complete, 130 interrupted, "
                                   "3 station failure, 2 bad input.")
    p.add_argument("scenario", help="scenario YAML (e.g. diagrams/paper000_emulated.yaml)")
    _add_scenario_options(p)
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true", help="continue the interrupted campaign in --out")
    p.add_argument("--no-fsync", action="store_true",
                   help="flush each reading to the OS but skip fsync (faster; a power cut may lose the last ones)")
    _add_meshcat_options(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("tracker-emulator", help="emulate a Leica laser tracker (emScon/CESAPI over TCP) on "
                                                "127.0.0.1 until Ctrl-C",
                       description="Serve the emScon protocol of a Leica laser tracker on 127.0.0.1:PORT "
                                   "(docs/tracker.md): a reflector at rest in the tracker's frame (--reflector-mm), "
                                   "or carried by the simulated robot of a six-axis scenario with station: "
                                   "!Tracker (--scenario; the robot controller is emulated on a pseudo-terminal, "
                                   "printed at start). Units mm, degrees, Celsius, hPa unless SetUnits says "
                                   "otherwise.")
    p.add_argument("--port", type=cliargs.integer(0, 65535), required=True,
                   help="TCP port (700 is a real tracker's; 0 picks a free one, printed)")
    p.add_argument("--reflector-mm", type=cliargs.pairs_mm(3), metavar="X,Y,Z",
                   help="a reflector at rest at X,Y,Z mm in the tracker's frame")
    p.add_argument("--scenario", help="a six-axis scenario YAML whose station is !Tracker: its robot carries the "
                                      "reflector through the campaign")
    p.add_argument("--seed", type=cliargs.seed, default=None,
                   help="noise, beam-break and drift seed (default: the scenario's, 0 without one)")
    p.set_defaults(func=cmd_tracker_emulator)
    return parser


#: Options whose values may start with '-' (negative angles, coordinates).
_SIGNED_VALUE_OPTIONS = ("--grid1-deg", "--grid2-deg", "--reflectors-mm", "--nominal-mm", "--stations-mm",
                         "--tool-offset-mm", "--tool-offsets-mm", "--reflector-mm")


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


def _interrupted(e: BaseException) -> bool:
    """Whether ``e`` is Ctrl-C, or an error it caused: an import interrupted inside an extension module
    (pybind11's "initialization failed") surfaces as ImportError chained to the KeyboardInterrupt."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _os_error_line(e: OSError) -> str:
    """One line for an OSError: the file it names and the system's reason."""
    where = ": ".join(os.fspath(f) for f in (e.filename, e.filename2) if f is not None)
    reason = e.strerror or " ".join(str(e).split()) or type(e).__name__
    return f"{where}: {reason}" if where else reason


def _quiet_stdout() -> None:
    """After a broken pipe (``olti ... | head``): point stdout at devnull so the exit flush is silent
    (the recipe of the Python documentation, signal module, "Note on SIGPIPE")."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _empty_argument(parser, args):
    """The one line for a path or value given as the empty string (``olti identify "" ...``), naming the
    argument or option; None when every one given is non-empty. Checked before any verb reads a file."""
    import argparse

    actions = list(parser._actions)
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction) and getattr(args, "verb", None) in a.choices:
            actions += a.choices[args.verb]._actions
    for a in actions:
        v = getattr(args, a.dest, None) if a.dest not in (None, argparse.SUPPRESS) else None
        if v == "" or (isinstance(v, (list, tuple)) and any(x == "" for x in v)):
            verb = f"olti {args.verb}" if getattr(args, "verb", None) else "olti"
            if a.option_strings:
                return f"{verb}: {a.option_strings[-1]} is empty: give a path or value"
            return f"{verb}: the {a.dest.replace('_', ' ')} path is empty (the {a.dest} argument)"
    return None


def _load_drake_with_sigint_held() -> None:
    """Import pydrake with SIGINT held: a Ctrl-C inside its C++ initialization makes pydrake print its own
    critical log line on stderr (spdlog, before Python sees the interrupt); held, the Ctrl-C arrives right after
    the import as the KeyboardInterrupt that main turns into its one line. Only where signals can be held (the
    main thread, POSIX) and pydrake is not loaded yet."""
    import importlib
    import threading

    if ("pydrake" in sys.modules or not hasattr(signal, "pthread_sigmask")
            or threading.current_thread() is not threading.main_thread()):
        return
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        importlib.import_module("pydrake")
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(_join_signed_values(sys.argv[1:] if argv is None else argv))
    empty = _empty_argument(parser, args)
    if empty is not None:
        print(f"error: {empty}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        _load_drake_with_sigint_held()
        code = args.func(args)
        sys.stdout.flush()               # a reader that went away is found here, not at exit
        return code
    except BrokenPipeError:
        _quiet_stdout()
        return 1
    except ValueError as e:              # bad input (errors.InputError and outputs.OutputError included)
        msg = " ".join(str(e).split()) or type(e).__name__
        if type(e).__name__ == "LinAlgError":  # numpy's bare "Singular matrix": what it means for the readings
            msg = (f"olti {getattr(args, 'verb', '')}: the readings cannot determine the solution (numerical "
                   f"failure: {msg}): check the readings' unit (mm) and sign (formats.md), and that no two stations "
                   f"or reflectors coincide")
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as e:                 # an output or input the system refuses: one line naming it
        print(f"error: {_os_error_line(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (KeyboardInterrupt, ImportError) as e:
        if not _interrupted(e):
            raise
        print(f"error: interrupted (olti {args.verb})", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
