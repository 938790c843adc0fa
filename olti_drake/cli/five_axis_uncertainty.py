"""``olti uncertainty`` of a five-axis machine result (``olti-machine5/1``; issue 25, item 5): argument handling and
printing only. The result is re-solved on its campaign (:func:`olti_drake.estimation.five_axis_uncertainty.
identification_at_result`), then propagated linearly (JCGM 100) or by Monte Carlo (JCGM 101) by the verb's
propagation (:func:`olti_drake.cli.propagate.propagate`), with the budget's reading errors or, without
``--budget``, the identification's own reading uncertainty. Units: mm, deg, µrad."""

import time


def uncertainty(args) -> int:
    """Standard uncertainties (k = 1) of every location error, error-motion value, tool offset and station of a
    five-axis result, in the result's keys and shapes (formats.md's ``uncertainty`` object)."""
    from olti_drake.cli.propagate import campaign_note, propagate
    from olti_drake.estimation.five_axis_uncertainty import (identification_at_result, reading_errors,
                                                             with_prior_spread)
    from olti_drake.estimation.uncertainty import uncertainty_dict
    from olti_drake.io.budget import load_budget
    from olti_drake.io.five_axis_io import file_sha256, load_machine5_result, read_five_axis_campaign
    from olti_drake.io.outputs import write_json

    t0 = time.perf_counter()
    res = load_machine5_result(args.result)
    campaign = read_five_axis_campaign(args.campaign, res.machine)
    ident, fit, note = identification_at_result(res, campaign, args.result)
    errors, budget, what = reading_errors(ident, fit, load_budget(args.budget) if args.budget else None)
    x = fit.x
    std, cov, samples, extra, every = propagate(ident, x, errors, args)
    std, samples, prior_notes = with_prior_spread(ident, x, errors, std, cov, samples, every, args.seed)
    extra["notes"] = list(extra.get("notes", [])) + prior_notes + [f"reading errors: {what}"]
    campaign_note(extra, note)
    extra.update(result=args.result, result_sha256=file_sha256(args.result), campaign=args.campaign,
                 budget_file=args.budget or "built-in: the identification's own reading uncertainty",
                 elapsed_s=round(time.perf_counter() - t0, 3))
    out = uncertainty_dict(ident, std, args.method, budget, k=args.k, samples=samples, coverage=args.coverage,
                           extra=extra)
    write_json(args.out, out)
    print(f"uncertainty ({args.method}) of the five-axis result {args.result} on {campaign.n_readings} readings; "
          f"{what}" + (f"; {len(every)} trials, seed {args.seed}" if every is not None else ""))
    print(summary(out, args.k))
    for line in extra["notes"]:
        print(f"  note: {line}")
    print(f"wrote {args.out}")
    return 0


def summary(unc: dict, k: float) -> str:
    """The expanded uncertainty U = k u of every location error and the largest U of each error motion (µm,
    µrad)."""
    import numpy as np

    lines = [f"  location errors, U (k = {k:g}):"]
    for name, u in unc["location_errors"].items():
        if name in unc.get("held", ()):
            continue
        unit, scale = ("um", 1e3) if name.endswith("_mm") else ("urad", 1.0)
        lines.append(f"    {name:<12} {scale * k * u:9.3f} {unit}")
    motions = unc.get("error_motions") or {}
    if motions:
        worst = []
        for name, m in motions.items():
            scale, unit = (1e3, "um") if m.get("unit") == "mm" else (1.0, "urad")
            U = scale * k * max(float(np.max(m[b])) for b in ("forward", "reverse") if b in m)
            worst.append(f"{name} {U:.2f} {unit}")
        lines.append(f"  error motions, largest U (k = {k:g}) on their grids: " + ", ".join(worst))
    return "\n".join(lines)
