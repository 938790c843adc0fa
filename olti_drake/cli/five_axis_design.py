"""``olti design`` for a five-axis result (``olti-machine5/1``): where to put stations and R-test nests (argument
handling and printing only; the method is :mod:`olti_drake.estimation.five_axis_design`)."""

import os
import sys
import time

import numpy as np


def design(args) -> int:
    """Stations (bed or table) and nests from the regions' candidates, cost = the worst or mean tool-point u from
    the location errors (linear, k = 1); writes DESIGN.json."""
    from olti_drake.estimation.five_axis_design import (FiveAxisDesignProblem, design_document, design_layout,
                                                        region_frames)
    from olti_drake.estimation.machine_design import default_step_mm
    from olti_drake.estimation.serial_design import load_boxes
    from olti_drake.io.budget import load_budget
    from olti_drake.io.five_axis_io import load_machine5_result
    from olti_drake.io.outputs import write_json
    from olti_drake.model.budget import ReadingErrors

    res = load_machine5_result(args.result)
    budget = load_budget(args.budget) if args.budget else None
    problem = FiveAxisDesignProblem(res, args.workspace_poses, args.seed,
                                    ReadingErrors(budget).std if budget is not None else None)
    boxes = load_boxes(args.regions)
    frames = region_frames(args.regions, len(boxes))
    derived = getattr(args, "step_mm_default", False) or args.step_mm is None
    step = default_step_mm(boxes, problem.tool_points_mm) if derived else args.step_mm
    positions, where = _candidates(boxes, frames, step)
    t0 = time.perf_counter()
    cand = problem.candidates(positions, where)
    doc = res.document
    stations = np.asarray(doc.get("stations_mm", []), float).reshape(-1, 3)
    current = (problem.candidates(stations, doc.get("station_frames", ["base"] * len(stations)))
               if len(stations) else None)
    n = args.reflectors if args.reflectors is not None else (len(stations) or 5)
    tty = sys.stderr.isatty()

    def report(start, sweep, cost):
        sys.stderr.write(f"\r  designing: start {start + 1}/{args.starts}, sweep {sweep + 1}/{args.max_sweeps}, "
                         f"cost {cost:.4g} mm, {time.perf_counter() - t0:.1f} s   ")
        sys.stderr.flush()

    d = design_layout(problem, cand, n, criterion=args.criterion, seed=args.seed, starts=args.starts,
                      max_sweeps=args.max_sweeps, min_separation_mm=args.min_separation_mm, current=current,
                      progress=report if tty else None)
    if tty:
        sys.stderr.write("\n")
    out = design_document(d, result=args.result, regions=args.regions, step_mm=step, criterion=args.criterion,
                          seed=args.seed, starts=args.starts, max_sweeps=args.max_sweeps,
                          min_separation_mm=args.min_separation_mm, workspace_poses=args.workspace_poses,
                          budget=budget.name if budget is not None else "1 um per reading (stated)",
                          elapsed_s=time.perf_counter() - t0)
    write_json(args.out, out)
    print(f"five-axis layout design ({os.path.basename(args.result)}): {n} stations/nests from {len(cand)} "
          f"candidates ({', '.join(f'{k} {v}' for k, v in out['candidates']['by_frame'].items() if v)}), "
          f"{args.criterion} tool-point u from the location errors (k = 1)")
    for name, layout in (("current", d.current), ("designed", d.designed)):
        if layout is None:
            continue
        u = layout.max_u_mm if args.criterion == "max" else layout.mean_u_mm
        print(f"  {name}: {args.criterion} u = {1e3 * u:.3f} um; "
              f"identifiable {len(layout.identifiable)}/{len(layout.location_u)}"
              + (f" (not: {', '.join(n for n, u in layout.location_u.items() if u is None)})"
                 if len(layout.identifiable) < len(layout.location_u) else ""))
    for e in out["designed"]["elements"]:
        print(f"    {e['kind']} ({e['frame']}) at {np.round(e['position_mm'], 3).tolist()} mm")
    for note in d.notes:
        print(f"note: {note}")
    print(f"wrote {os.fspath(args.out)}")
    return 0


def _candidates(boxes, frames, step):
    """(positions (C, 3) mm, frames (C,)): each region's grid (serial_design.candidate_points), its frame."""
    from olti_drake.estimation.serial_design import candidate_points

    pts, where = [], []
    for box, f in zip(boxes, frames):
        p = candidate_points(box[None], step)
        pts.append(p)
        where += [f] * len(p)
    return np.vstack(pts), np.asarray(where, dtype=object)
