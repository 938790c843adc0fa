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
    from .figures import write_campaign_figures

    t0 = time.perf_counter()
    setup, campaign, paths = _simulate(None, args.out)
    print("paper 000 experiment, simulated (open-loop tracking interferometer on a SCARA robot)")
    print(_summary(setup, campaign, time.perf_counter() - t0))
    print(f"wrote {paths[0]} and {paths[1]}")
    for path in write_campaign_figures(setup, campaign, args.out):
        print(f"wrote {path}")
    print("identification of the D-H and error-map models: not yet available in this version")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="olti", description="Open-loop tracking interferometer calibration (mm and degrees).")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    p = sub.add_parser("demo", help="simulate the paper-000 experiment and summarize it; write figures",
                       description="Simulate the paper-000 SCARA experiment on the embedded default "
                                   "scenario, summarize the campaign and write figures (PNG).")
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
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from .csvio import InputError

    try:
        return args.func(args)
    except (InputError, ValueError, FileNotFoundError) as e:
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
