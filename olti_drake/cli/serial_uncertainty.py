"""``olti uncertainty`` for a robot identified from a model file (argument handling and printing; the method is
:mod:`olti_drake.estimation.serial_uncertainty` and :mod:`olti_drake.estimation.uncertainty`).

Every result ``olti identify`` writes is taken: the quadratic costs its identification had -- the maps' smoothness
prior (``smoothing.weight``), the ``--regularize`` priors (``priors``, or rebuilt by the identification's rule for a
result that records none) -- are re-added to the program at the result, and their own spread is propagated with
the readings' (``estimation.serial_uncertainty.prior_spread``). Without ``--budget`` a robot is propagated with its
own reading uncertainty (``result_budget``: the SCARA model's 000 Table 2; any other robot the residual standard
deviation of its identification), never another robot's budget. A tracker campaign's points have three residual
rows each (``CoordinateErrors``)."""

import time


def uncertainty(args) -> int:
    """Standard uncertainties of every parameter of a serial result (linear or Monte Carlo, by the verb's
    propagation, :func:`olti_drake.cli.propagate.propagate`), and of the predicted tool point over
    ``--workspace-poses`` seeded poses (``--map``: slices)."""
    import numpy as np

    from olti_drake.cli.propagate import propagate
    from olti_drake.estimation.resolution import inflation_note
    from olti_drake.estimation.serial_uncertainty import (CoordinateErrors, calibration_at_result, prior_spread,
                                                          restore_priors, result_budget, workspace_uncertainty,
                                                          zero_held_uncertainties)
    from olti_drake.estimation.uncertainty import uncertainty_dict
    from olti_drake.io.budget import budget_or_default
    from olti_drake.io.csvio import check_campaign_matches
    from olti_drake.io.outputs import write_json
    from olti_drake.io.serial_io import load_serial_result, read_serial_campaign
    from olti_drake.model.budget import ReadingErrors

    t0 = time.perf_counter()
    res = load_serial_result(args.result, outside="clamp", identified=True)
    campaign = read_serial_campaign(args.campaign, res.model.chain.n_joints, robot=res.data["robot"]["file"])
    note = check_campaign_matches(res.data, campaign, args.result)
    cal, x = calibration_at_result(res, campaign)
    priors = restore_priors(cal, res, x)  # the identification's quadratic costs: smoothing, --regularize
    if args.budget:
        budget, budget_text = budget_or_default(args.budget, "scara"), args.budget
    else:  # the robot's own: never the SCARA's Table 2 for another robot (estimation.serial_uncertainty)
        budget, budget_text = result_budget(res, args.result, cal, x)
    errors = ReadingErrors(budget)
    if campaign.kind == "point":  # three residual rows per tracker point
        errors = CoordinateErrors(errors)
    std, cov, samples, extra, every = propagate(cal, x, errors, args)
    if priors.Q is not None:  # the priors' own spread (their centres are held in the propagation)
        u2 = float(np.mean(errors.std(cal.beam_lengths(x)) ** 2))
        if cov is not None:
            cov = prior_spread(cal, x, priors, u2, cov=cov)
            std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        else:
            every = prior_spread(cal, x, priors, u2, samples=every, seed=args.seed)
            samples = every if samples is not None else None
            std = every.std(axis=0, ddof=1)
        priors.notes.append(f"the priors' own spread added: each a pseudo-reading of the budget's reading variance "
                            f"({1e3 * np.sqrt(u2):.3f} um RMS), as weighed in the identification")
    extra["notes"] = list(extra.get("notes", [])) + priors.notes + [t for t in [inflation_note(res.data)] if t]
    if note:
        extra["notes"] = list(extra.get("notes", [])) + [note]
    n = res.model.n_params
    ws = workspace_uncertainty(res.model, args.workspace_poses, args.seed,
                               cov=None if cov is None else cov[:n, :n],
                               samples=None if every is None else every[:, :n])
    U = 1e3 * args.k * ws["u_norm_mm"]
    extra.update(budget_file=budget_text, result=args.result, campaign=args.campaign,
                 elapsed_s=round(time.perf_counter() - t0, 3),
                 workspace={"poses": int(args.workspace_poses), "seed": args.seed, "k": args.k,
                            "expanded_um_max": float(U.max()), "expanded_um_mean": float(U.mean()),
                            "what": "k * sqrt(u_x^2 + u_y^2 + u_z^2) of the predicted tool point at seeded poses in "
                                    "the model's commanded ranges"})
    out = zero_held_uncertainties(uncertainty_dict(cal, std, args.method, budget, k=args.k, samples=samples,
                                                   coverage=args.coverage, extra=extra), cal.measurement)
    write_json(args.out, out)
    print(f"uncertainty ({args.method}) of {args.result} ({res.model.chain.n_joints} joints) on {len(campaign)} "
          f"readings; budget {budget.name!r}" + (f"; {len(every)} trials, seed {args.seed}" if every is not None
                                                 else ""))
    worst = int(np.argmax(std[:n] / np.maximum(np.abs(x[:n]), 1e-12)))
    print(f"  {n} model parameters; the largest relative u: {cal.names[worst]} = {x[worst]:.6g} +- {std[worst]:.3g}")
    print(f"  predicted tool point over {args.workspace_poses} workspace poses: U (k = {args.k:g}) max "
          f"{U.max():.2f} um, mean {U.mean():.2f} um")
    for line in extra.get("notes", []):
        print(f"  note: {line}")
    print(f"wrote {args.out}")
    if args.map:
        from olti_drake.report.serial_report import plot_workspace_uncertainty

        plot_workspace_uncertainty(ws["points_mm"], U, args.map, args.k,
                                   f"{'Monte Carlo' if every is not None else 'linear'}, budget {budget.name}")
        print(f"wrote {args.map}")
    return 0
