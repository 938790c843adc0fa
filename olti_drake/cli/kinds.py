"""The kinds in the ``olti`` command: which body runs a verb on which kind, and the one table of options by kind.

Three registries tell the kinds apart, each in one place: the calibration kinds
(:func:`olti_drake.estimation.problem.kind_of`: ``olti identify``, ``olti multilaterate``), the result kinds
(:func:`olti_drake.io.documents.read_result`: every verb that takes a result) and the scenario kinds
(:func:`olti_drake.sim.serial_scenario.scenario_kind`: ``olti simulate``, ``plan``, ``run``). A verb asks once,
refuses here the options that do not apply to the kind (:data:`OPTIONS`, :func:`refuse_inapplicable`) and runs
the kind's body (:data:`HANDLERS`). Only the standard library is imported: ``olti --help`` stays fast.
"""

from dataclasses import dataclass
from typing import Dict, Optional, Tuple

from olti_drake.named import resolve

#: The body of each verb for each result kind it takes ("module:function", imported when run; the function
#: takes the parsed ``args``). A kind missing here is refused by :func:`result_kind_of`.
HANDLERS = {
    "predict": {"scara": "olti_drake.cli.scara_verbs:predict",
                "serial": "olti_drake.cli.serial_verbs:predict",
                "volumetric": "olti_drake.cli.volumetric_verbs:predict",
                "machine5": "olti_drake.cli.five_axis_verbs:predict"},
    "uncertainty": {"scara": "olti_drake.cli.scara_verbs:uncertainty",
                    "serial": "olti_drake.cli.serial_uncertainty:uncertainty",
                    "multilateration": "olti_drake.cli.machine_verbs:uncertainty",
                    "volumetric": "olti_drake.cli.volumetric_verbs:uncertainty",
                    "machine5": "olti_drake.cli.five_axis_uncertainty:uncertainty"},
    "design": {"scara": "olti_drake.cli.scara_verbs:design",
               "serial": "olti_drake.cli.serial_design:design",
               "multilateration": "olti_drake.cli.machine_design:design",
               "volumetric": "olti_drake.cli.machine_design:design",
               "machine5": "olti_drake.cli.five_axis_design:design"},
    "compensate": {"scara": "olti_drake.cli.scara_verbs:compensate",
                   "serial": "olti_drake.cli.serial_verbs:compensate",
                   "volumetric": "olti_drake.cli.volumetric_verbs:compensate",
                   "machine5": "olti_drake.cli.five_axis_verbs:compensate"},
}

#: ``olti uncertainty --trials`` when not given, by result kind (else 1000): a five-axis trial re-solves hundreds of
#: map values (~20 ms each on a small campaign), 200 trials give u to ~5 %.
MC_TRIALS = {"machine5": 200}

#: The body of each verb that takes a campaign (not a result), by calibration kind
#: (:data:`olti_drake.estimation.problem.KINDS`' names); another kind is refused in one line (:data:`CAMPAIGN_REFUSED`).
CAMPAIGN_HANDLERS = {
    "validate": {"serial": "olti_drake.cli.validate:validate"},
}

#: A campaign verb's sentence for a kind it does not take ({campaign}: the file, {what}: what the kind is).
CAMPAIGN_REFUSED = {
    "validate": "olti validate: {campaign} is {what}; cross-validation takes the campaigns of N-joint robots from a "
                "model file for now (--robot FILE|ur5 --tool-frame NAME)",
}

#: A verb's own sentence for a result kind it does not take ({path}: the file), instead of read_result's.
REFUSED: Dict[Tuple[str, str], str] = {}  # (none now: every verb takes every result kind it lists)

_SCARA_PATH = "the SCARA path uses --nominal-mm and --grid1-deg/--grid2-deg"
_ROBOT = "needs --robot FILE --tool-frame NAME (a serial robot)"


@dataclass(frozen=True)
class Option:
    """An option of ``verb`` that applies to ``kinds`` only: given (its value is not ``unset``, the parser's
    default) for another kind, it is refused with ``refusals[kind]`` (else ``refusals[None]``; ``{flag}``)."""

    verb: str
    flag: str
    dest: str
    kinds: Tuple[str, ...]
    refusals: Dict[Optional[str], str]
    unset: object = None


def _scara_only(flag: str, dest: str, instead: str, unset=None) -> Option:
    return Option("identify", flag, dest, ("scara",), {
        "serial": f"{{flag}} is a SCARA option; with --robot the model uses {instead}",
        "volumetric": "{flag} applies to the SCARA models (dh, errormap), not to --model volumetric",
        None: "{flag} applies to the SCARA models (dh, errormap), not to a five-axis machine (--machine)"}, unset)


def _robot_only(flag: str, dest: str, unset=None) -> Option:
    return Option("identify", flag, dest, ("serial",), {
        "scara": f"{{flag}} {_ROBOT}; {_SCARA_PATH}",
        "volumetric": f"{{flag}} {_ROBOT}, not --model volumetric",
        None: f"{{flag}} {_ROBOT}, not a five-axis machine (--machine)"}, unset)


def _volumetric_only(flag: str, dest: str, unset=None) -> Option:
    return Option("identify", flag, dest, ("volumetric",), {None: "{flag} applies to --model volumetric"}, unset)


#: Every option that applies to some kinds only, by verb: the one place where the others are refused.
#: (``olti multilaterate`` has one kind; ``olti report`` checks its files itself: report.html.write_report.)
OPTIONS = (
    # olti identify: the calibration kinds (estimation.problem.kind_of)
    Option("identify", "--tool-offsets-mm", "tool_offsets_mm", ("volumetric", "machine5"),
           {None: "{flag} applies to --model volumetric and to five-axis machines (--machine FILE)"}),
    Option("identify", "--knot-spacing-mm", "knot_spacing_mm", ("volumetric", "machine5"),
           {None: "{flag} applies to --model volumetric and to a five-axis machine's linear axes (--machine FILE)"}),
    _volumetric_only("--topology", "topology", "serial"),
    _volumetric_only("--pitch-mm", "pitch_mm"),
    Option("identify", "--robot", "robot", ("serial",),
           {None: "{flag} applies to the robot models (dh, errormap), not to --model volumetric"}),
    Option("identify", "--tool-frame", "tool_frame", ("serial", "machine5"),
           {None: "{flag} needs --robot FILE (an N-joint robot model) or --machine FILE (a five-axis machine)"}),
    Option("identify", "--workpiece-frame", "workpiece_frame", ("machine5",),
           {None: "{flag} needs --machine FILE (a five-axis machine model)"}),
    Option("identify", "--linear", "linear", ("machine5",),
           {None: "{flag} (a five-axis machine's linear axes: identify, perfect or a volumetric result) needs "
                  "--machine FILE (a five-axis machine model)"}),
    _scara_only("--grid1-deg", "grid1_deg", "--grid-step-deg"),
    _scara_only("--grid2-deg", "grid2_deg", "--grid-step-deg"),
    _scara_only("--nominal-mm", "nominal_mm", "the robot file's geometry and --tool-offset-mm"),
    _scara_only("--reflectors-mm", "reflectors_mm", "the stations fitted to the nominal tool points"),
    _scara_only("--fix-reflectors", "fix_reflectors", "the stations fitted to the nominal tool points", False),
    _robot_only("--tool-offset-mm", "tool_offset_mm"),
    Option("identify", "--grid-step-deg", "grid_step_deg", ("serial", "machine5"), {
        "scara": f"{{flag}} {_ROBOT} or --machine FILE; {_SCARA_PATH}",
        None: "{flag} needs --robot FILE --tool-frame NAME or --machine FILE (error-map nodes every S deg)"}),
    _robot_only("--compliance", "compliance", False),
    _robot_only("--drift", "drift", False),
    _robot_only("--cv", "cv"),
    Option("identify", "--smoothing", "smoothing", ("serial", "scara", "volumetric", "machine5"),
           {None: "{flag} applies to error maps and error motions (--model errormap, volumetric), not to the "
                  "multilateration's free targets"}),
    # olti uncertainty: the result kinds (io.documents.read_result)
    Option("uncertainty", "--maps", "maps", ("scara",), {
        "serial": "{flag} is the SCARA figure; for a robot from a model file the maps with these error bars are in "
                  "olti report RESULT.json UNC.json",
        "multilateration": "{flag} (error maps with error bars) applies to SCARA error-map results only",
        "machine5": "{flag} is the SCARA figure; a five-axis result's error motions with U bands are in olti report "
                    "RESULT.json UNC.json"}),
    Option("uncertainty", "--map", "map", ("scara", "serial", "multilateration"),
           {None: "{flag} (U over the workspace) applies to robots and machine-tool targets; a five-axis result's "
                  "error motions with U bands are in olti report RESULT.json UNC.json"}),
    Option("uncertainty", "--workspace-poses", "workspace_poses", ("serial",),
           {None: "{flag} applies to robots from a model file (olti identify --robot); the SCARA's map and the "
                  "machine's targets are where they are"}, 400),
    # olti design
    Option("design", "--plan", "plan", ("scara", "serial"),
           {None: "{flag} applies to robots (a SCARA or --robot result); a machine tool's design takes the result's "
                  "targets"}),
    Option("design", "--workspace-step-mm", "workspace_step_mm", ("scara",),
           {None: "{flag} applies to SCARA results (its XY grid); robots from a model file use --workspace-poses"},
           50.0),
    Option("design", "--workspace-poses", "workspace_poses", ("serial", "machine5"),
           {None: "{flag} applies to robots from a model file (olti identify --robot) and five-axis machines"}, 300),
    Option("design", "--clearance-mm", "clearance_mm", ("scara", "serial"),
           {None: "{flag} applies to robots (the arm's clearance); a machine tool's design takes none"}, 50.0),
    Option("design", "--base-radius-mm", "base_radius_mm", ("scara", "serial"),
           {None: "{flag} applies to robots (beams past the base); a machine tool's design takes none"}, 40.0),
    *(Option("design", flag, dest, ("serial", "multilateration", "volumetric"),
             {None: "{flag}: a SCARA design searches its starts in this process (one memo of layouts); the designs "
                    "of robots from a model file and of machine tools take it"}, unset)
      for flag, dest, unset in (("--workers", "workers", None), ("--backend", "backend", "loky"),
                                ("--scheduler", "scheduler", None))),
    # olti compensate
    Option("compensate", "--urdf-out", "urdf_out", ("serial",),
           {None: "{flag} needs the result of a robot model file (olti identify --robot)"}),
    Option("compensate", "--cartesian-out", "cartesian_out", ("serial",),
           {None: "{flag} (pre-distorted Cartesian targets for the controller's IK) needs the result of a robot "
                  "model file (olti identify --robot)"}),
    Option("compensate", "--ur-kinematics-out", "ur_kinematics_out", ("serial",),
           {None: "{flag} (a UR-style default_kinematics.yaml) needs the result of a robot model file (olti "
                  "identify --robot)"}),
    Option("compensate", "--dh-out", "dh_out", ("serial",),
           {None: "{flag} (a D-H table) needs the result of a robot model file (olti identify --robot)"}),
    Option("compensate", "--ros2-control-out", "ros2_control_out", ("serial",),
           {None: "{flag} (joint offsets for ros2_control) needs the result of a robot model file (olti identify "
                  "--robot)"}),
    Option("compensate", "--elbow", "elbow", ("scara",),
           {None: "{flag} applies to SCARA results (a robot from a model file keeps its nominal pose's)"}, 1),
    Option("compensate", "--pitch-mm", "pitch_mm", ("volumetric",),
           {None: "{flag} applies to volumetric results (--tables: the axis tables)"}),
    Option("compensate", "--grid-pitch-mm", "grid_pitch_mm", ("volumetric",),
           {None: "{flag} applies to volumetric results (--tables: the 3D grid)"}),
    Option("compensate", "--cnc", "cnc", ("machine5",),
           {None: "{flag} (the files a five-axis controller loads) needs the result of a five-axis machine (olti "
                  "identify --machine FILE)"}),
    # olti run: the scenario kinds (sim.serial_scenario.scenario_kind)
    Option("run", "--meshcat", "meshcat", ("scara",),
           {None: "{flag}: olti run shows the live view of SCARA campaigns only; the six-axis and 3D machine "
                  "campaigns run without it ({scenario}; olti simulate shows a six-axis one)"}, False),
)


def refuse_inapplicable(verb: str, kind: str, args) -> None:
    """Refuse (one line, ValueError) the first option of ``verb`` given for a ``kind`` it does not apply to."""
    for o in OPTIONS:
        if o.verb == verb and kind not in o.kinds and getattr(args, o.dest, o.unset) != o.unset:
            text = o.refusals.get(kind, o.refusals.get(None))
            raise ValueError(text.format(flag=o.flag, scenario=getattr(args, "scenario", "")))


def handler(verb: str, kind: str):
    """The body of ``verb`` for ``kind`` (:data:`HANDLERS`)."""
    return resolve(HANDLERS[verb][kind])


def campaign_handler(verb: str, args):
    """The body of the campaign verb ``verb`` for the kind of ``args.campaign`` (:data:`CAMPAIGN_HANDLERS`): a robot
    model given (``--robot``) is the serial kind, else a machine-tool campaign (``x_cmd_mm``) or the SCARA's;
    a kind ``verb`` does not take refused in one line (:data:`CAMPAIGN_REFUSED`)."""
    if getattr(args, "robot", None):
        kind, what = "serial", "an N-joint robot's campaign"
    else:
        from olti_drake.io.serial_io import header

        machine = "x_cmd_mm" in header(args.campaign)[1]
        kind, what = (("multilateration", "a machine-tool campaign") if machine else
                      ("scara", "a SCARA campaign (no --robot given)"))
    if kind not in CAMPAIGN_HANDLERS[verb]:
        raise ValueError(CAMPAIGN_REFUSED[verb].format(campaign=args.campaign, what=what))
    refuse_inapplicable(verb, kind, args)
    return resolve(CAMPAIGN_HANDLERS[verb][kind])


def result_kind_of(args, verb: str) -> str:
    """The kind of ``args.result`` (:func:`olti_drake.io.documents.read_result`: any result file, old ones
    included), refused in one line naming the file when ``verb`` does not take it; then the options of
    ``verb`` that do not apply to that kind are refused (:func:`refuse_inapplicable`)."""
    from olti_drake.io.documents import not_taken, read_result

    kind, doc = read_result(args.result, tuple(HANDLERS[verb]), refuse=False)
    if kind not in HANDLERS[verb]:
        if (verb, kind) in REFUSED:
            raise ValueError(REFUSED[verb, kind].format(path=args.result))
        raise not_taken(args.result, kind, doc, tuple(HANDLERS[verb]), f"olti {verb}")
    refuse_inapplicable(verb, kind, args)
    return kind
