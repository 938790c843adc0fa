"""``olti uncertainty``'s propagation, shared by every kind's body: linear (JCGM 100) or Monte Carlo (JCGM 101)
through the identification program of the result, by the method of the command line."""

import sys


def propagate(ident, x, errors, args):
    """(std, cov or None, samples for coverage intervals or None, extra dict, all samples or None) by the
    method of ``args`` (linear or mc); the intervals only when enough trials make them reliable."""
    import numpy as np

    from olti_drake.estimation.uncertainty import linear_covariance, monte_carlo, trials_for_intervals

    if args.method == "linear":
        cov = linear_covariance(ident, x, errors)
        return (np.sqrt(np.maximum(np.diag(cov), 0.0)), cov, None,
                {"method_detail": "linear propagation through the identification Jacobian (JCGM 100), "
                                  "budget reading errors"}, None)
    tty = sys.stderr.isatty()

    def report(done, total):
        sys.stderr.write(f"\r  Monte Carlo: {done} trials" + (" (adaptive, at most " if args.adaptive else " of ")
                         + f"{total}{')' if args.adaptive else ''}")
        sys.stderr.flush()

    mc = monte_carlo(ident, x, errors, trials=args.trials, seed=args.seed, workers=args.workers,
                     adaptive=args.adaptive, max_trials=args.max_trials, coverage=args.coverage,
                     progress=report if tty else None, backend=getattr(args, "backend", "loky"),
                     scheduler=getattr(args, "scheduler", None))
    if tty:
        sys.stderr.write("\n")
    notes = list(mc.notes)
    if not mc.intervals_adequate:
        notes.append(f"coverage intervals not reported: {len(mc.samples)} trials "
                     + ("did not stabilize them (JCGM 101 §7.9)" if args.adaptive else
                        f"are fewer than the 10^4/(1 - p) = {trials_for_intervals(args.coverage)} JCGM 101 §7.2.2 "
                        f"asks for p = {args.coverage:g} (use --adaptive or more --trials)"))
    return (mc.samples.std(axis=0, ddof=1), None, mc.samples if mc.intervals_adequate else None,
            {"method_detail": "Monte Carlo (JCGM 101): budget errors drawn for every reading, the problem "
                              "re-solved per trial", "trials": int(len(mc.samples)), "seed": args.seed,
             "adaptive": bool(args.adaptive), "converged": bool(mc.converged), "notes": notes,
             **({"max_trials": args.max_trials} if args.adaptive else {})}, mc.samples)


def campaign_note(extra: dict, note: str) -> None:
    """Add the campaign-digest note (older results carry no digest) to the uncertainty file's notes."""
    if note:
        extra["notes"] = list(extra.get("notes", [])) + [note]
