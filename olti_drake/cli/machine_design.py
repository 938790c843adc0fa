"""``olti design`` for a 3D machine-tool result (multilateration or volumetric): station layout in 3D (argument
handling and printing only; the method is :mod:`olti_drake.estimation.machine_design`)."""

import os
import sys
import time


def design(args) -> int:
    """Heads for a 3D multilateration campaign of the result's targets: candidates on a grid in the 3D regions,
    cost = the worst or mean target u (linear, the budget; default 001 Table 4); writes DESIGN.json."""
    from olti_drake.estimation.machine_design import (MachineStationInformation, default_step_mm,
                                                      design_machine_stations, design_targets, estimated_seconds,
                                                      evaluate_machine_layout, machine_design_document)
    from olti_drake.estimation.serial_design import candidate_points, load_boxes
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.outputs import write_json
    from olti_drake.model.budget import ReadingErrors

    targets = design_targets(args.result)
    n = args.reflectors if args.reflectors is not None else (
        0 if targets.stations_mm is None else len(targets.stations_mm))
    budget = budget_or_default(args.budget, "machine")
    boxes = load_boxes(args.regions)
    # --step-mm not given: a step from the regions' size, about DEFAULT_CANDIDATES candidates
    derived = getattr(args, "step_mm_default", False) or args.step_mm is None
    step = default_step_mm(boxes, targets.targets_mm) if derived else args.step_mm
    cand = candidate_points(boxes, step)
    t0 = time.perf_counter()
    info = MachineStationInformation(targets.targets_mm, targets.nominal_mm, targets.gauge_kind, ReadingErrors(budget))
    tty = sys.stderr.isatty()
    most = estimated_seconds(len(targets.targets_mm), len(cand), n, args.starts, args.max_sweeps)

    def report(start, sweep, cost):
        sys.stderr.write(f"\r  designing: start {start + 1}/{args.starts}, sweep {sweep + 1}/{args.max_sweeps}, "
                         f"{args.criterion} u = {1e3 * cost:.3f} um, {time.perf_counter() - t0:.1f} s (at most ~{most:.0f} s)   ")
        sys.stderr.flush()

    d = design_machine_stations(info, cand, n, criterion=args.criterion, seed=args.seed, starts=args.starts,
                                max_sweeps=args.max_sweeps, min_separation_mm=args.min_separation_mm,
                                regions=args.regions, progress=report if tty else None, workers=args.workers or 1,
                                backend=args.backend, scheduler=args.scheduler)
    if tty:
        sys.stderr.write("\n")
    current = None
    if targets.stations_mm is not None and len(targets.stations_mm) >= 4:
        current = evaluate_machine_layout(info, targets.stations_mm, args.criterion)
    doc = machine_design_document(d, current, targets, budget_name=budget.name, result=args.result,
                                  regions=args.regions, step_mm=step, seed=args.seed,
                                  max_sweeps=args.max_sweeps, min_separation_mm=args.min_separation_mm,
                                  gauge=info.gauge, elapsed_s=time.perf_counter() - t0)
    write_json(args.out, doc)
    print(f"station layout design in 3D (machine tool, {os.path.basename(args.result)}) by linear propagation "
          f"(JCGM 100), budget {budget.name!r}")
    print(f"  targets: {targets.what}; cost: {args.criterion} target u")
    print(f"  candidates: {len(cand)} on a {step:g} mm grid in {args.regions}"
          + (" (--step-mm not given: from the regions' size)" if derived else ""))
    from olti_drake.cli.serial_design import print_layouts

    print_layouts(doc, current, n, d.evaluations, args, "the multilateration cannot solve from these stations", 3)
    return 0
