"""The machine-tool multilateration, 2D (paper 001) or 3D (the machine tool in 3D, formats.md): the summary of
``olti multilaterate`` (whose route is :mod:`olti_drake.cli.identify`'s) and ``olti uncertainty`` of its result:
argument handling and printing only; the work is in :mod:`olti_drake.estimation.multilateration` and
:mod:`olti_drake.estimation.uncertainty`. mm. numpy is imported inside the verbs: ``olti --help`` builds the parser
without it."""


def _norm_um(v_mm):
    """The 2-norm of each row (N, D) mm, in µm."""
    import numpy as np

    return 1e3 * np.sqrt(np.sum(np.square(v_mm), axis=1))


def summary(res, data) -> str:
    """A short account of a multilateration (``res``, a MultilaterationResult) of the campaign ``data``."""
    dev = _norm_um(res.targets_mm - res.nominal_mm)
    U = 2 * _norm_um(res.targets_std_mm)
    lines = [f"multilateration (001 Eq. 2-6, {data.dim}D): {len(data)} readings, {data.n_targets} targets, "
             f"{data.n_stations} stations, {len(res.fit.names)} parameters, solver {res.fit.solver}",
             f"  target deviation from command: max {dev.max():.2f} um, mean {dev.mean():.2f} um; "
             f"U (k = 2) of the 2-norm: max {U.max():.2f} um"]
    for j, (P, L0) in enumerate(zip(res.stations_mm, res.dead_paths_mm)):
        lines.append(f"  station {j}: ({', '.join(f'{v:.4f}' for v in P)}) mm, dead path {L0:.4f} mm")
    lines.append(f"  residual RMS {1e3 * res.residual_rms_mm:.3f} um, {res.fit.iterations} iterations, "
                 f"condition number {res.fit.condition_number:.3g}")
    lines.append(f"  gauge: {res.gauge}")
    lines += [f"  note: {note}" for note in res.fit.notes if note.startswith("tool offsets")]
    lines += [f"  warning: {warning}" for warning in res.fit.warnings]
    from olti_drake.estimation.calibration import suspect_readings_line

    lines += [t for t in [suspect_readings_line(res.fit.outliers)] if t]
    return "\n".join(lines)


def uncertainty(args) -> int:
    """``olti uncertainty`` of a machine-tool result (001 §4.4, Fig. 14), 2D or 3D: targets, stations, dead
    paths, by the verb's linear / Monte Carlo propagation (:func:`olti_drake.cli.propagate.propagate`)."""
    import time

    import numpy as np

    from olti_drake.cli.propagate import campaign_note, propagate
    from olti_drake.estimation.multilateration import (Multilateration, MultilaterationOptions, load_machine_campaign,
                                                       load_result)
    from olti_drake.estimation.uncertainty import uncertainty_dict
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.csvio import check_campaign_matches
    from olti_drake.io.outputs import write_json
    from olti_drake.model.budget import ReadingErrors
    from olti_drake.report.figures import plot_target_uncertainty

    t0 = time.perf_counter()
    res = load_result(args.result)
    budget = budget_or_default(args.budget, "machine")
    data = load_machine_campaign(args.campaign)
    D = data.dim
    if np.shape(res["targets_mm"])[1] != D:
        raise ValueError(f"{args.result}: a {np.shape(res['targets_mm'])[1]}D result, but {args.campaign} is a "
                         f"{D}D campaign")
    note = check_campaign_matches(res, data, args.result)
    ident = Multilateration(data, MultilaterationOptions(stations_mm=res["stations_mm"], gauge=res["gauge_kind"],
                                                         tool_offsets_mm=res.get("tool_offsets_mm")))
    x = np.concatenate([np.ravel(res["targets_mm"]), np.ravel(res["stations_mm"]), res["dead_paths_mm"]])
    if len(x) != len(ident.names):
        raise ValueError(f"{args.result}: its targets/stations do not match the campaign {args.campaign}")
    std, _, samples, extra, every = propagate(ident, x, ReadingErrors(budget), args)
    campaign_note(extra, note)
    U = args.k * _norm_um(std[:D * data.n_targets].reshape(-1, D))
    norm = "sqrt(u_x^2 + u_y^2)" if D == 2 else "sqrt(u_x^2 + u_y^2 + u_z^2)"
    extra.update(gauge=res["gauge"], elapsed_s=round(time.perf_counter() - t0, 3),
                 target_expanded_um={"k": args.k, "max": float(U.max()), "mean": float(U.mean()),
                                     "what": f"k * {norm} of every estimated target (001 Fig. 14)"})
    out = uncertainty_dict(ident, std, args.method, budget, k=args.k, samples=samples, coverage=args.coverage,
                           extra=extra)
    write_json(args.out, out)
    print(f"uncertainty ({args.method}) of the {D}D multilateration {args.result} on {len(data)} readings; budget "
          f"{budget.name!r}" + (f"; {len(every)} trials, seed {args.seed}" if every is not None else ""))
    print(f"  targets: U (k = {args.k:g}) of the 2-norm max {U.max():.2f} um, mean {U.mean():.2f} um")
    for note in extra.get("notes", []):
        print(f"  note: {note}")
    print(f"wrote {args.out}")
    if args.map:
        plot_target_uncertainty(data.commands_mm, U, args.map, args.k,
                                f"{'Monte Carlo' if every is not None else 'linear'}, budget {budget.name}")
        print(f"wrote {args.map}")
    return 0


def add_multilaterate_options(p, cliargs) -> None:
    """The options of ``olti multilaterate`` that depend on the dimension (2D pairs or 3D triples, mm)."""
    p.add_argument("--stations-mm", type=cliargs.points_mm(),
                   help="initial station positions 'x,y;x,y;...' (2D) or 'x,y,z;...' (3D) mm (001 §2.2 estimates; "
                        "default: from the data)")
    p.add_argument("--gauge", choices=("best-fit", "first-two", "first-three"), default=None,
                   help="best-fit: no mean translation/rotation of the targets from their commands (default); "
                        "first-two (2D): target 0 at its command, target 1 on its command direction; first-three "
                        "(3D): and the first target off that line in the plane of their commands")
    p.add_argument("--tool-offsets-mm", type=cliargs.points_mm(),
                   help="3D: nominal offsets 'x,y,z;...' mm of the campaign's tool indices 0, 1, ... (default: "
                        "zero for one tool; estimated from the readings relative to tool 0 for several)")
