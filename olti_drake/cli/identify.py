"""``olti identify`` and ``olti multilaterate``: one route for every kind of calibration (issue 22; the five-axis
machine, issue 25).

campaign CSV -> :func:`olti_drake.calibration_problem` (the options of the command line by their option names)
-> ``problem.fit()`` (the default LM) -> the result document (``format`` and ``kind``, formats.md) -> written ->
the summary printed. The kind is asked once (:func:`olti_drake.estimation.problem.kind_of`); the options that do
not apply to it are refused by the one table (:mod:`olti_drake.cli.kinds`); what differs by kind is only how the
command line spells its options and the summary (:data:`ROUTES`); the document is the kind's own writer's
(``Identification.document``). Units: mm and degrees.
"""

import os
from dataclasses import dataclass
from typing import Callable


def _solver_options(args, default_loss: str = "l2") -> dict:
    """The shared solver options (calibration.SolverOptions); ``default_loss`` when --loss is not given (the
    serial robots' ``auto``; the SCARA and machine kinds keep ``l2``); --max-iterations only when given (else
    the cap that fits the problem's size)."""
    loss = getattr(args, "loss", None)
    o = dict(loss=loss if loss is not None else default_loss, huber_k=args.huber_k,
             outlier_threshold=args.outlier_threshold, regularize=args.regularize, solver=args.solver)
    if getattr(args, "max_iterations", None) is not None:
        o["max_iterations"] = int(args.max_iterations)
    return o


# -- the SCARA of paper 000 ------------------------------------------------------------------------------------
def _scara_options(args) -> dict:
    from olti_drake.estimation.identification import parse_grid

    nominal = args.nominal_mm[0] if args.nominal_mm else (325.0, 225.0)
    o = dict(nominal_L1_mm=nominal[0], nominal_L2_mm=nominal[1],
             grid1_deg=parse_grid(args.grid1_deg, "--grid1-deg") if args.grid1_deg else None,
             grid2_deg=parse_grid(args.grid2_deg, "--grid2-deg") if args.grid2_deg else None,
             reflectors_mm=args.reflectors_mm, fix_reflectors=args.fix_reflectors, budget=args.budget,
             # (off by default: the paper's campaigns command every node both ways; the prior is there to ask for)
             smoothing="off" if args.smoothing is None else args.smoothing, **_solver_options(args))
    if args.fix_reflectors and args.reflectors_mm is None:
        raise ValueError("--fix-reflectors needs --reflectors-mm")
    return o


def _scara_summary(ident, doc, problem) -> str:
    from olti_drake.cli.scara_verbs import identification_summary

    return identification_summary(ident)


# -- an N-joint robot from its model file ----------------------------------------------------------------------
def _robot_input(spec):
    """The robot file an argument names, as an input never to be written (None for a shipped name)."""
    from olti_drake.io.serial_io import SHIPPED_ROBOTS

    return None if spec is None or spec.lower() in SHIPPED_ROBOTS else spec


def _serial_check(args) -> None:
    if not args.tool_frame:
        raise ValueError(f"--robot {args.robot}: give the tool frame with --tool-frame NAME")
    if args.tool_offset_mm and len(args.tool_offset_mm) != 1:
        raise ValueError(f"--tool-offset-mm: one point x,y,z (mm), got {len(args.tool_offset_mm)}")


def _serial_options(args) -> dict:
    return dict(tool_frame=args.tool_frame,
                tool_offset_mm=tuple(args.tool_offset_mm[0]) if args.tool_offset_mm else (0.0, 0.0, 0.0),
                grid_step_deg=args.grid_step_deg,
                compliance=args.compliance, drift=args.drift, budget=args.budget,
                smoothing="auto" if args.smoothing is None else args.smoothing, **_solver_options(args, "auto"))


def _chain(problem):
    return problem.program.measurement.model.chain


def _serial_notes(problem) -> None:
    for note in _chain(problem).notes:  # said once, before the work (and kept in the result's notes)
        print(f"note: {note}", flush=True)


def _serial_summary(ident, doc, problem) -> str:
    from olti_drake.estimation.serial_identification import summary

    return summary(ident)


# -- the machine-tool multilateration of 001, 2D or 3D --------------------------------------------------------------
def _campaign_dim(path) -> int:
    """2, or 3 when the machine campaign has ``z_cmd_mm`` (its header; the loader checks the rest)."""
    from olti_drake.io.serial_io import header

    return 3 if "z_cmd_mm" in header(path)[1] else 2


def _multilateration_options(args) -> dict:
    from olti_drake.estimation.multilateration import GAUGES_BY_DIM

    dim = _campaign_dim(args.campaign)
    for option, value in (("--stations-mm", args.stations_mm), ("--tool-offsets-mm", args.tool_offsets_mm)):
        if value is not None and any(len(v) != dim for v in value):
            raise ValueError(f"{option}: {args.campaign} is a {dim}D campaign: give {dim} coordinates per position "
                             f"(mm)")
    gauge = args.gauge or "best-fit"
    if gauge not in GAUGES_BY_DIM[dim]:
        raise ValueError(f"--gauge {gauge}: a {dim}D campaign ({args.campaign}) takes "
                         f"{' or '.join(GAUGES_BY_DIM[dim])}")
    return dict(stations_mm=args.stations_mm, gauge=gauge, tool_offsets_mm=args.tool_offsets_mm, budget=args.budget,
                **_solver_options(args))


def _multilateration_summary(res, doc, problem) -> str:
    from olti_drake.cli.machine_verbs import summary

    return summary(res, problem.program.data)


# -- the 21 ISO 230-1 error motions of a 3-axis machine -------------------------------------------------------------
def _volumetric_options(args) -> dict:
    return dict(tool_offsets_mm=args.tool_offsets_mm, knot_spacing_mm=args.knot_spacing_mm, topology=args.topology,
                pitch_mm=args.pitch_mm or 10.0, budget=args.budget,
                smoothing="off" if args.smoothing is None else args.smoothing, **_solver_options(args))


def _volumetric_summary(res, doc, problem) -> str:
    from olti_drake.cli.volumetric_verbs import summary

    return summary(res, doc, problem.program.data)


# -- a five-axis machine from its model file ------------------------------------------------------------------------
def _machine5_options(args) -> dict:
    return dict(machine=args.machine, workpiece_frame=args.workpiece_frame, tool_frame=args.tool_frame,
                pitch_deg=args.grid_step_deg or 15.0, tool_offsets_mm=args.tool_offsets_mm, budget=args.budget,
                smoothing="auto" if args.smoothing is None else args.smoothing,
                linear=getattr(args, "linear", None) or "auto", knot_spacing_mm=args.knot_spacing_mm,
                **_solver_options(args))


def _linear_input(args):
    """The ``--linear`` volumetric result (an input never to be written), not the words auto / identify / perfect."""
    from olti_drake.estimation.five_axis import LINEAR_WORDS

    linear = getattr(args, "linear", None)
    return None if linear is None or linear in LINEAR_WORDS else linear


def _machine5_summary(fit, doc, problem) -> str:
    from olti_drake.cli.five_axis_verbs import summary

    return summary(problem.program, fit, doc)


def _machine5_before(problem) -> None:
    for g, why in problem.program.dropped.items():  # said before the work (and kept in the result's notes)
        print(f"note: {g}: not separable by this campaign ({why}): held at 0", flush=True)


# -- the route ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Route:
    """How one calibration kind spells its part of the route: ``check(args)`` (the command line alone, before the
    outputs are checked), ``options(args)`` (calibration_problem's options), ``inputs(args)`` (files never to be
    written), ``before(problem)`` (said before the fit), ``summary(result, document, problem)`` (``result`` the
    kind's own). The document is the kind's own writer's (``Identification.document``, estimation.problem.KINDS),
    the same a Python user's ``fit.write(path)`` writes."""

    options: Callable
    summary: Callable
    inputs: Callable = lambda args: [args.campaign, args.budget]
    check: Callable = lambda args: None
    before: Callable = lambda problem: None


#: The part of the route each calibration kind spells its own (estimation.problem.KINDS' names).
ROUTES = {
    "scara": Route(_scara_options, _scara_summary),
    "serial": Route(_serial_options, _serial_summary, check=_serial_check, before=_serial_notes,
                    inputs=lambda args: [args.campaign, args.budget, _robot_input(args.robot)]),
    "multilateration": Route(_multilateration_options, _multilateration_summary),
    "volumetric": Route(_volumetric_options, _volumetric_summary),
    "machine5": Route(_machine5_options, _machine5_summary, before=_machine5_before,
                      inputs=lambda args: [args.campaign, args.budget, args.machine, _linear_input(args)]),
}


def _problem(kind: str, args, model: str, options: dict):
    """``od.calibration_problem`` of the campaign (``olti multilaterate --budget residuals`` included)."""
    from olti_drake.estimation.problem import calibration_problem

    return calibration_problem(args.campaign, model=model, robot=args.robot if kind == "serial" else None,
                               **options)


def identify(args, model: str) -> int:
    """The route (module doc) for ``model`` = dh | errormap (SCARA, or an N-joint robot with ``--robot``),
    volumetric or multilateration; with ``--machine`` (a five-axis machine) geometric | errormap."""
    from olti_drake.cli.kinds import refuse_inapplicable
    from olti_drake.estimation.problem import kind_of
    from olti_drake.io.outputs import preflight, write_json

    robot, machine = getattr(args, "robot", None), getattr(args, "machine", None)
    kind = kind_of(model, robot if model in ("dh", "errormap") else None, machine).name
    refuse_inapplicable(args.verb, kind, args)
    route = ROUTES[kind]
    route.check(args)
    preflight([args.out], [i for i in route.inputs(args) if i], force=getattr(args, "force", False))
    problem = _problem(kind, args, model, route.options(args))
    route.before(problem)
    fit = problem.fit()
    doc = fit.document(args.out)
    write_json(args.out, doc)
    print(route.summary(fit.result, doc, problem))
    print(f"wrote {os.fspath(args.out)}")
    return 0
