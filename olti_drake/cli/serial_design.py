"""``olti design`` for a serial robot's result: station placement in 3D (argument handling and printing only;
the method is :mod:`olti_drake.estimation.serial_design`)."""

import os
import time

import numpy as np


def design(args) -> int:
    """Stations for a campaign of the result's robot: the result's model is the truth, its stations the current
    layout; candidates on a grid in the 3D regions; cost = the worst or mean predicted tool-point u."""
    from olti_drake.estimation.serial_design import (StationInformation, candidate_points, candidates_in_plane,
                                                     design_document, design_stations, evaluate_layout, gauge_rows,
                                                     load_boxes, workspace_poses)
    from olti_drake.estimation.serial_plan import reading_uncertainty_mm
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.outputs import write_json
    from olti_drake.io.serial_io import load_serial_result, read_joint_table
    from olti_drake.model.chain import plane_frame, robot_plane

    res = load_serial_result(args.result, outside="clamp")
    model = res.model
    # A planar model (the planar problem: stations in the robot's plane) is designed in that plane.
    plane = robot_plane(model.chain, model.chain_params) if model.planar_reduced else None
    n = args.reflectors if args.reflectors is not None else (0 if res.stations_mm is None else len(res.stations_mm))
    need, why = (3, "in a planar robot's plane (000 §3.2.2 Remark 1)") if plane is not None else (
        4, "for a robot in 3D (3 leave the tool on a plane of mirror solutions)")
    if n < need:
        raise ValueError(f"--reflectors (stations) must be >= {need} {why}, got {n}" + (
            "" if args.reflectors is not None else f" (the result {args.result} has {n})"))
    if args.plan:
        jt = read_joint_table(args.plan, model.chain.n_joints)
        plan, dirs, plan_name = jt.commands, jt.dirs, args.plan
        if model.bidirectional and dirs is None:
            raise ValueError(f"{args.plan}: no dir1..dir{model.chain.n_joints} columns, but the result's maps are "
                             f"bidirectional: the plan must say how each pose is approached")
        dirs = dirs if model.bidirectional else None
    else:
        plan, dirs = workspace_poses(model, 600, args.seed + 1)
        plan_name = "600 seeded random poses in the result's commanded ranges (no --plan)"
    budget = budget_or_default(args.budget, "scara")
    u = reading_uncertainty_mm(budget)
    boxes = load_boxes(args.regions)
    cand = candidate_points(boxes, args.step_mm)
    where = "in 3D"
    if plane is not None:
        level = float(np.mean(model.positions(plan, dirs) @ plane_frame(plane)[0]))
        cand = candidates_in_plane(cand, plane, level, args.step_mm, args.regions)
        where = "in the planar robot's plane"
    t0 = time.perf_counter()
    ref = res.stations_mm if res.stations_mm is not None and len(res.stations_mm) >= need else cand[:need]
    A, sentence = gauge_rows(model, plan, dirs, ref, seed=args.seed, plane=plane)
    info = StationInformation(model, plan, dirs, u, workspace_poses(model, args.workspace_poses, args.seed + 2),
                              gauge_rows=A, plane=plane, base_radius_mm=args.base_radius_mm,
                              clearance_mm=args.clearance_mm)
    current = evaluate_layout(info, res.stations_mm, args.criterion) if res.stations_mm is not None else None
    d = design_stations(info, cand, n, criterion=args.criterion, seed=args.seed, starts=args.starts,
                        max_sweeps=args.max_sweeps, min_separation_mm=args.min_separation_mm,
                        workers=args.workers or 1, backend=args.backend, scheduler=args.scheduler)
    doc = design_document(d, current, budget_name=budget.name, u_reading_mm=u, result=args.result, plan=plan_name,
                          regions=args.regions, step_mm=args.step_mm, seed=args.seed, max_sweeps=args.max_sweeps,
                          min_separation_mm=args.min_separation_mm, workspace_poses=args.workspace_poses,
                          gauge=sentence, elapsed_s=time.perf_counter() - t0)
    write_json(args.out, doc)
    print(f"station layout design {where} ({os.path.basename(res.robot_path)}, {model.chain.n_joints} joints) by linear "
          f"propagation (JCGM 100), budget {budget.name!r}, u(reading) = {1e3 * u:.2f} um")
    print(f"  plan: {plan_name}; {len(plan)} poses; cost: {args.criterion} predicted tool-point u over "
          f"{args.workspace_poses} workspace poses")
    print(f"  candidates: {len(cand)} on a {args.step_mm:g} mm grid, {doc['candidates']['feasible']} see enough poses")
    print_layouts(doc, current, n, d.evaluations, args, "the campaign cannot identify the model from these stations")
    return 0


def print_layouts(doc: dict, current, n: int, evaluations: int, args, unsolvable: str, digits: int = 2) -> None:
    """The current and designed layouts' costs and positions, the improvement, the search (um, mm)."""
    for label, c in (("current (result)", current), (f"designed ({n} stations)", doc["designed"])):
        if c is None:
            continue
        if np.isfinite(c["cost_mm"]):
            print(f"  {label:24s} max u {1e3 * c['max_u_mm']:8.{digits}f} um, "
                  f"mean u {1e3 * c['mean_u_mm']:8.{digits}f} um")
        else:
            print(f"  {label:24s} {unsolvable}")
        print("    at " + ", ".join("(" + ", ".join(f"{v:.0f}" for v in s) + ")" for s in c["stations_mm"]) + " mm")
    if doc["improvement"] is not None:
        print(f"  improvement ({args.criterion} u, current / designed): {doc['improvement']:.2f}x")
    print(f"  {evaluations} layouts evaluated from {args.starts} start(s), seed {args.seed}, {doc['elapsed_s']:.1f} s")
    print(f"wrote {args.out}")
