"""``olti validate`` (and ``olti identify --cv K``): K-fold cross-validation by pose of an N-joint robot's models.

``olti validate CAMPAIGN.csv --robot FILE|ur5 --tool-frame NAME [identify options] [--folds K] [--models
dh,errormap:30,...] [--seed S] --out CV.json``: parse -> one library call
(:func:`olti_drake.estimation.validation.cross_validate`) -> the table printed -> CV.json written (its keys: the
module doc of :mod:`olti_drake.estimation.validation`). The identify options are those of ``olti identify
--robot`` and mean the same (built by the same :func:`olti_drake.cli.identify._serial_options`); every candidate
model carries them.

``olti identify ... --robot FILE --cv K``: the same validation of the default candidates (and of the model asked,
at its ``--grid-step-deg``) is printed first; then the model asked by ``--model`` is identified and written as
usual, with a note when the validation recommends another one. It writes no CV.json (``olti validate`` does).
Serial robots only for now: other kinds are refused in one line (:data:`olti_drake.cli.kinds.CAMPAIGN_HANDLERS`).
"""

import dataclasses
import os


def _options(args):
    """(chain, campaign, SerialIdentificationOptions) from the identify options on the command line."""
    from olti_drake.cli.identify import _serial_check, _serial_options
    from olti_drake.estimation.problem import _budget, _options as checked
    from olti_drake.estimation.serial_identification import SerialIdentificationOptions
    from olti_drake.io.serial_io import load_robot, read_serial_campaign

    _serial_check(args)
    o = _serial_options(args)
    frame = o.pop("tool_frame")
    o["budget"] = _budget(o)
    options = checked(SerialIdentificationOptions, o, "olti validate")
    chain = load_robot(args.robot, frame)
    campaign = read_serial_campaign(args.campaign, chain.n_joints, robot=args.robot)
    return chain, campaign, options


def _check_folds(args) -> None:
    if args.folds < 2:
        raise ValueError(f"olti {args.verb}: --folds {args.folds}: cross-validation needs at least 2 folds")


def validate(args) -> int:
    """The verb body (module doc)."""
    from olti_drake.cli.identify import _robot_input
    from olti_drake.estimation.validation import cross_validate, parse_models, table
    from olti_drake.io.outputs import preflight, write_json
    from olti_drake.io.serial_io import robot_reference

    _check_folds(args)
    step = 15.0 if args.grid_step_deg is None else args.grid_step_deg
    models = None if args.models is None else parse_models(args.models, step)  # (bad names: before any work)
    preflight([args.out], [i for i in (args.campaign, args.budget, _robot_input(args.robot)) if i],
              force=getattr(args, "force", False))
    chain, campaign, options = _options(args)
    cv = cross_validate(chain, campaign, options, folds=args.folds, models=models, seed=args.seed)
    cv["robot"] = {"file": robot_reference(args.robot, args.out), "tool_frame": args.tool_frame}
    print(table(cv))
    write_json(args.out, cv)
    print(f"wrote {os.fspath(args.out)}")
    return 0


def cv_before_identify(args) -> None:
    """``olti identify --cv K``: the validation printed before the identification of ``--model`` (module doc)."""
    from olti_drake.cli.kinds import refuse_inapplicable
    from olti_drake.estimation.problem import kind_of
    from olti_drake.estimation.validation import cross_validate, default_candidates, parse_models, table
    from olti_drake.io.outputs import preflight

    kind = kind_of(args.model, getattr(args, "robot", None) if args.model in ("dh", "errormap") else None).name
    refuse_inapplicable("identify", kind, args)
    args.folds = args.cv
    _check_folds(args)
    from olti_drake.cli.identify import _robot_input

    preflight([args.out], [i for i in (args.campaign, args.budget, _robot_input(args.robot)) if i],
              force=getattr(args, "force", False))
    chain, campaign, options = _options(args)
    asked = parse_models([args.model], options.grid_step_deg)[0]
    asked = dataclasses.replace(asked, compliance=bool(options.compliance), drift=bool(options.drift))
    models = default_candidates(chain, campaign, options)
    models += [] if asked.name in {c.name for c in models} else [asked]
    cv = cross_validate(chain, campaign, options, folds=args.cv, models=models, seed=0)
    print(table(cv))
    if cv["recommended"] != asked.name:
        print(f"note: the validation recommends {cv['recommended'] or 'no model'}; identifying --model "
              f"{args.model} as asked (olti validate --out CV.json writes the validation)")
