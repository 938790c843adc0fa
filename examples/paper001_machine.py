"""Reproduce the machine-tool experiment of paper 001 (§2.2-§4) in simulation.

An XY machining centre with volumetric errors (``olti_drake.model.machine``), the
20 perimeter targets of a 100 × 100 mm square in 20 mm steps, the
interferometer's rotary table at three positions Pos A-C, 001 Table 4's
budget:

1. initial estimation of every station (001 §2.2, Figs. 6-7): rotation centre
   and zero angle by the simulated procedures of ``olti_drake.estimation.station_estimation``;
2. the campaign (numpy twin ``simulate_machine_campaign``; its aiming errors
   drawn with the uncertainties the procedures state) and the self-calibrating
   multilateration (001 §2.3), started from the estimated stations;
3. the references of 001 §3.2 (``olti_drake.sim.references``): a 2D digital scale
   (Fig. 10) and a linear laser interferometer along X and along Y (Fig. 13);
4. the Monte Carlo uncertainty of the target positions (001 §4.4, Fig. 14).

Writes fig06_07_station_estimation.png, fig10_targets.png,
fig13_linear_errors.png and fig14_uncertainty.png into ``--out`` and prints
the comparisons. Units: mm; µm for errors, µrad for the zero angles::

    python examples/paper001_machine.py --out paper001_out
    python examples/paper001_machine.py --stations-mm="-60,-60;160,-60;50,160"   # closer in: max U ≈ 7.5 µm
"""

import argparse
import dataclasses
import os

import numpy as np

from olti_drake.model.budget import ReadingErrors, paper001_budget
from olti_drake.report import figures
from olti_drake.model.machine import MachineScenario, simulate_machine_campaign, square_targets
from olti_drake.estimation.multilateration import Multilateration, MultilaterationOptions, align_to_commands, machine_campaign
from olti_drake.sim.references import DigitalScale, LinearInterferometer, line_errors, on_line, remove_offset
from olti_drake.estimation.station_estimation import (CentreOptions, RotaryStation, ZeroAngleOptions, estimate_rotation_centre,
                                           estimate_zero_angle, positioning_accuracy_um)
from olti_drake.estimation.uncertainty import monte_carlo

#: 001 §3.2: where the linear interferometer measured (Y for the X line, X for the Y line), mm.
LASER_LINES = {"x": 52.3, "y": 71.3}
#: 001 Fig. 13: where the multilateration's profiles are taken (Y = 0 for E_XX, X = 100 mm for E_YY).
ESTIMATE_LINES = {"x": 0.0, "y": 100.0}


def estimate_stations(scenario, commands, budget, rng):
    """001 §2.2 for every station: (centre estimates, zero-angle estimates)."""
    machine = scenario.error
    stations = np.asarray(scenario.stations_mm, dtype=float)
    # The operator states the machine's positioning accuracy over the table as a ± bound (ISO 230-2).
    accuracy = positioning_accuracy_um(machine, np.vstack([stations, commands]))
    middle = commands.mean(axis=0)
    centres, zeros = [], []
    for P in stations:
        station = RotaryStation(axis_mm=tuple(P), mount_deg=rng.uniform(-3, 3))
        start = P + 0.3 * rng.uniform(-1, 1, 2)  # "approximately on the axis": within the acceptance
        rough = station.mount_deg + rng.normal(0, 2.0)  # the table's zero is only roughly known before Fig. 7
        centres.append(estimate_rotation_centre(station, machine, start, budget, rng,
                                                CentreOptions(zero_rough_deg=rough, machine_accuracy_um=accuracy)))
        toward = 150.0 if P[0] <= middle[0] else -150.0  # the Y line the target moves on lies toward the work zone
        zeros.append(estimate_zero_angle(station, machine, budget, rng, ZeroAngleOptions(target_distance_mm=toward)))
    return centres, zeros


def line_panel(axis, est_mm, U_axis_um, commands, truth_mm, profile):
    """One panel of Fig. 13: the estimate along its line vs the laser, offsets removed (µm)."""
    at = ESTIMATE_LINES[axis]
    pos, e = line_errors(est_mm, commands, axis, at)
    _, t = line_errors(truth_mm, commands, axis, at)
    U = U_axis_um[on_line(commands, axis, at), 0 if axis == "x" else 1]
    name, other = ("E_XX", "Y") if axis == "x" else ("E_YY", "X")
    return {"title": f"{'a' if axis == 'x' else 'b'}) {name}: estimate at {other} = {at:g} mm, "
                     f"laser at {other} = {LASER_LINES[axis]:g} mm",
            "xlabel": f"{axis.upper()} command, mm", "ylabel": f"{name} (offset removed), µm",
            "position_mm": pos, "estimate_um": remove_offset(e), "expanded_um": U, "truth_um": remove_offset(t),
            "laser_position_mm": profile.position_mm, "laser_um": remove_offset(profile.error_um),
            "laser_bound_um": profile.bound_um}


def parse_stations(text):
    """'x,y;x,y;...' (mm) to a list of [x, y]."""
    return [[float(v) for v in pair.split(",")] for pair in text.split(";")]


def report_stations(scenario, centres, zeros):
    print("Initial estimation (001 §2.2; paper: 11.5 µm and 2.8 µrad, k = 2):")
    for j, (P, ce, ze) in enumerate(zip(scenario.stations_mm, centres, zeros)):
        print(f"  Pos {chr(ord('A') + j)} at ({P[0]:g}, {P[1]:g}) mm: centre error ({ce.error_um[0]:+.1f}, "
              f"{ce.error_um[1]:+.1f}) µm, U(k=2) {ce.expanded_um[0]:.1f} µm; zero angle error "
              f"{1e6 * ze.error_rad:+.1f} µrad, U(k=2) {2e6 * ze.std_rad:.1f} µrad "
              f"(Y reference line tilt {1e6 * ze.reference_tilt_rad:+.1f} µrad)")


def campaign_and_fit(scenario, centres, zeros, budget):
    """Simulate the campaign and multilaterate from the estimated stations: (program, result, truth).

    The tables aim (Eq. 1 of 001) with what the §2.2 procedures found: their station estimates,
    and zero angles off by the alignment error plus the tilt of the Y reference line they aligned to.
    """
    estimates = np.array([ce.estimate_mm for ce in centres])
    scenario = dataclasses.replace(scenario, stations_estimate_mm=estimates.tolist(),
                                   zero_angles_urad=[1e6 * (ze.error_rad + ze.reference_tilt_rad) for ze in zeros])
    cols, truth = simulate_machine_campaign(scenario, budget)
    ident = Multilateration(machine_campaign(cols), MultilaterationOptions(stations_mm=estimates))
    res = ident.solve(budget)
    _, stations = align_to_commands(truth["targets_mm"], res.commands_mm, truth["stations_mm"])
    n = 2 * len(res.commands_mm)
    U_st = 2e3 * np.hypot(*res.fit.std[n:n + 2 * len(stations)].reshape(-1, 2).T)
    print(f"Multilateration: {res.fit.iterations} iterations, residual RMS {1e3 * res.residual_rms_mm:.2f} µm; "
          f"stations {1e3 * np.hypot(*(res.stations_mm - stations).T).max():.1f} µm from the truth at most "
          f"(U(k=2) up to {U_st.max():.1f} µm; the §2.2 estimates: "
          f"{np.max([np.hypot(*ce.error_um) for ce in centres]):.1f} µm)")
    return ident, res, truth


def target_uncertainty(ident, res, budget, trials, seed, truth_t):
    """Monte Carlo (001 §4.4) standard uncertainties (N_i, 2) mm of the targets; prints max U(k=2)."""
    mc = monte_carlo(ident, res.fit.x, ReadingErrors(budget), trials=trials, seed=seed)
    std = mc.samples.std(axis=0, ddof=1)[:2 * len(res.commands_mm)].reshape(-1, 2)
    U_mc, U_lin = 2e3 * np.hypot(*std.T), 2e3 * np.hypot(*res.targets_std_mm.T)
    err = 1e3 * np.hypot(*(res.targets_mm - truth_t).T)
    print(f"max U(k=2) = {U_mc.max():.2f} µm (Monte Carlo, {len(mc.samples)} trials; linear {U_lin.max():.2f} µm; "
          f"mean {U_mc.mean():.2f} µm; paper ≈ 8 µm)")
    print(f"  estimate − truth: max {err.max():.2f} µm (max |error|/U = {np.max(err / U_mc):.2f})")
    return std


def compare_scale(actual, res, rng):
    """001 Fig. 10: the 2D digital scale against the estimate (best-fit gauge); returns its readings."""
    plate, seed = DigitalScale(), int(rng.integers(2 ** 32))
    raw = plate.measure(actual, res.commands_mm, seed)
    # The same seed: the same plate, its growth compensated with the nominal α and T.
    fixed = dataclasses.replace(plate, compensate=True).measure(actual, res.commands_mm, seed)
    d_raw, d_fixed = (1e3 * np.hypot(*(p - res.targets_mm).T).max() for p in (raw, fixed))
    print(f"Digital scale − multilateration: max {d_raw:.2f} µm (the plate at {plate.temperature_C:g} °C reads "
          f"{plate.scale_difference_um():.2f} µm per 100 mm short); with its growth compensated: "
          f"max {d_fixed:.2f} µm")
    return raw


def compare_lasers(machine, res, std, truth_t, rng):
    """001 Fig. 13: E_XX and E_YY of the estimate against the linear laser interferometer; the panels."""
    panels = []
    for axis in ("x", "y"):
        laser = LinearInterferometer(axis=axis, at_mm=LASER_LINES[axis])
        profile = laser.measure(machine, np.unique(res.commands_mm[:, 0 if axis == "x" else 1]), rng)
        p = line_panel(axis, res.targets_mm, 2e3 * std, res.commands_mm, truth_t, profile)
        diff = np.abs(p["estimate_um"] - np.interp(p["position_mm"], p["laser_position_mm"], p["laser_um"]))
        print(f"{'E_XX' if axis == 'x' else 'E_YY'}: multilateration − laser interferometer (offsets removed): "
              f"max {diff.max():.2f} µm (U(k=2) up to {p['expanded_um'].max():.2f} µm)")
        panels.append(p)
    return panels


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="paper001_out", help="directory for the figures (default paper001_out)")
    parser.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    parser.add_argument("--trials", type=int, default=2000, help="Monte Carlo trials (default 2000)")
    parser.add_argument("--stations-mm", type=parse_stations, default=None,
                        help="station positions 'x,y;x,y;x,y' mm (default: MachineScenario's Pos A-C)")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    seeds = np.random.SeedSequence(args.seed).spawn(3)
    budget = paper001_budget()
    scenario = MachineScenario(seed=args.seed, **({"stations_mm": args.stations_mm} if args.stations_mm else {}))

    centres, zeros = estimate_stations(scenario, square_targets(scenario.size_mm, scenario.step_mm), budget,
                                       np.random.default_rng(seeds[0]))
    report_stations(scenario, centres, zeros)
    ident, res, truth = campaign_and_fit(scenario, centres, zeros, budget)
    actual = np.asarray(truth["targets_mm"])
    truth_t, truth_s = align_to_commands(actual, res.commands_mm, truth["stations_mm"])
    std = target_uncertainty(ident, res, budget, args.trials, int(seeds[1].generate_state(1)[0]), truth_t)
    rng = np.random.default_rng(seeds[2])
    plate = compare_scale(actual, res, rng)
    panels = compare_lasers(scenario.error, res, std, truth_t, rng)

    def out(name):
        return os.path.join(args.out, name)

    paths = [figures.plot_station_estimation(centres, zeros, out("fig06_07_station_estimation.png")),
             figures.plot_machine_targets(res.commands_mm, truth_s, res.targets_mm, out("fig10_targets.png"),
                                          station_estimates_mm=[ce.estimate_mm for ce in centres], scale_mm=plate,
                                          truth_mm=truth_t),
             figures.plot_linear_errors(panels, out("fig13_linear_errors.png")),
             figures.plot_target_uncertainty(res.commands_mm, 2e3 * np.hypot(*std.T), out("fig14_uncertainty.png"),
                                             method=f"Monte Carlo (JCGM 101), {args.trials} trials, "
                                                    "001 Table 4 budget")]
    print("wrote " + ", ".join(paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
