"""Validation of identified models on commands that were not in the identification (000 §4.3).

Paper 000 checks its models against a commercial laser tracker (AT960-XR) on
the path X = 200 mm, Y = -500 ... 500 mm (Figs. 9-10) and on a grid of
Cartesian paths over the workspace (Fig. 11). Here the simulated tracker
(:mod:`olti_drake.sim.tracker`) reads the simulated robot's *actual* positions,
and each model's prediction is compared with that reading.

Registration (why a rotation is fitted): distances cannot see a rotation of
the whole frame about the J1 axis -- the identification fixes it by a gauge
convention (``Identification.gauge``), not by physics -- and a tracker
measures in its own frame, which the paper had to register to the robot too.
So each model's predictions are rotated about the J1 axis (the origin) by the
rotation that best fits the measured positions (2D Procrustes, closed form, no
translation: the origin *is* the J1 axis in both) before the errors are taken.
The rotation is fitted per model and per command set, so neither model is
favoured; one scalar per set cannot absorb a shape error.

Units: mm and degrees; RMS and max errors in mm (the demo prints µm).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence

import numpy as np

from olti_drake.estimation.compensation import register  # noqa: F401 (re-exported)
from olti_drake.io.csvio import CampaignData
from olti_drake.model.scara import (PAPER_L1_MM, PAPER_L2_MM, JointCommands, ScaraModel, forward_kinematics,
                         inverse_kinematics)
from olti_drake.sim.tracker import LaserTrackerSpec, measure_positions, path_commands

#: The identified map range of the paper's plan (000 Eq. 11-12), deg.
PAPER_THETA1_RANGE = (-140.0, 60.0)
PAPER_THETA2_RANGE = (0.0, 140.0)

#: Independent random streams derived from the validation seed.
STREAM_RANDOM_COMMANDS, STREAM_TRACKER = 0, 1


# -- campaign -> identification input --------------------------------------------------------------
def campaign_data(campaign) -> CampaignData:
    """The valid readings of a simulated :class:`~olti_drake.sim.campaign.Campaign` as CampaignData.

    Same content as writing ``campaign.csv`` and reading it back with
    ``load_campaign`` (mm, deg), without the file. ``line`` holds the 1-based
    *row number* in the campaign (beam-lost rows counted), not a file line.
    """
    c = campaign.columns
    keep = c["valid"] > 0
    cmd = JointCommands(c["theta1_deg"][keep], c["theta2_deg"][keep], c["dir1"][keep], c["dir2"][keep])
    return CampaignData(c["reflector"][keep].astype(int), cmd, c["displacement_mm"][keep],
                        np.flatnonzero(keep) + 1, "simulated campaign (line = row number)",
                        int((~keep).sum()))


# -- command sets not used in the identification -----------------------------------------------------
@dataclass(frozen=True)
class CommandSet:
    """Validation commands with their nominal command positions (000 §4.3).

    ``commands``: θ1*, θ2* (deg) and per-axis approach directions;
    ``xy_cmd_mm`` (N, 2): the command positions (nominal Eq. (3) of 000);
    ``pass_dir`` (N,): +1 on a path's forward pass, -1 on its return pass
    (random commands: dir1), the red/blue of Figs. 9-11;
    ``path_id`` (N,): which straight path a point belongs to (random: 0).
    """

    name: str
    commands: JointCommands
    xy_cmd_mm: np.ndarray
    pass_dir: np.ndarray
    path_id: np.ndarray

    def __len__(self) -> int:
        return len(self.commands)


def _paths(name: str, lines: Sequence[np.ndarray], L1_mm: float, L2_mm: float) -> CommandSet:
    """Each line (K_i, 2) mm traversed forward and back with ``tracker.path_commands``, concatenated."""
    cmds, xy, pass_dir, ids = [], [], [], []
    for i, line in enumerate(lines):
        cmds.append(np.column_stack(path_commands(line[:, 0], line[:, 1], L1_mm, L2_mm)))
        xy.append(np.vstack([line, line[::-1]]))  # path_commands: forward pass, then the return
        pass_dir.append(np.repeat([1.0, -1.0], len(line)))
        ids.append(np.full(2 * len(line), i))
    c = np.vstack(cmds)
    return CommandSet(name, JointCommands(*c.T), np.vstack(xy), np.concatenate(pass_dir), np.concatenate(ids))


def x200_path(L1_mm: float = PAPER_L1_MM, L2_mm: float = PAPER_L2_MM, x_mm: float = 200.0,
              y_start_mm: float = -500.0, y_stop_mm: float = 500.0, step_mm: float = 25.0) -> CommandSet:
    """The measured path of 000 Fig. 7 / Figs. 9-10: X = 200 mm, Y = -500 ... 500 mm, forward and back.

    Commands come from the *nominal* link lengths L1, L2 (mm), as a robot
    controller would compute them. Note: near Y = 0 this path needs θ2* up to
    142.6° (paper robot), beyond the paper's J2 map range [0, 140]°.
    """
    y = np.arange(y_start_mm, y_stop_mm + step_mm / 2, step_mm)
    return _paths(f"X = {x_mm:g} mm path", [np.column_stack([np.full_like(y, x_mm), y])], L1_mm, L2_mm)


def _in_range(xy, L1_mm, L2_mm, theta1_range, theta2_range) -> np.ndarray:
    """Mask of points (K, 2) mm reachable (elbow +1) with θ1*, θ2* inside the ranges (deg)."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    reach = (r >= abs(L1_mm - L2_mm)) & (r <= L1_mm + L2_mm)
    t = np.full((2, len(xy)), np.nan)  # NaN fails every range test below
    if reach.any():
        t[:, reach] = inverse_kinematics(xy[reach, 0], xy[reach, 1], L1_mm, L2_mm, elbow=1)
    return ((t[0] >= theta1_range[0]) & (t[0] <= theta1_range[1])
            & (t[1] >= theta2_range[0]) & (t[1] <= theta2_range[1]))


def _segments(points: np.ndarray, keep: np.ndarray, min_points: int) -> list:
    """The runs of consecutive kept points, each at least ``min_points`` long."""
    idx = np.flatnonzero(keep)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []
    return [points[r] for r in runs if r.size >= min_points]


def grid_paths(L1_mm: float = PAPER_L1_MM, L2_mm: float = PAPER_L2_MM,
               theta1_range=PAPER_THETA1_RANGE, theta2_range=PAPER_THETA2_RANGE,
               line_spacing_mm: float = 200.0, step_mm: float = 50.0, min_points: int = 3) -> CommandSet:
    """Fig. 11-style grid of straight Cartesian paths, each forward and back (000 §4.3).

    X-paths (moving in X) at Y = k · ``line_spacing_mm`` and Y-paths at
    X = k · ``line_spacing_mm``, points every ``step_mm`` (mm). Points
    unreachable or outside the map range (θ1* in ``theta1_range``, θ2* in
    ``theta2_range``, deg; elbow θ2 ≥ 0) are dropped; a path broken by dropped
    points becomes separate paths of at least ``min_points`` points, so no
    command leaves the identified range. Commands use the nominal L1, L2 (mm).
    """
    reach = L1_mm + L2_mm
    ticks = np.arange(-np.floor(reach / step_mm), np.floor(reach / step_mm) + 1) * step_mm
    levels = np.arange(-np.floor(reach / line_spacing_mm), np.floor(reach / line_spacing_mm) + 1) * line_spacing_mm
    lines = []
    for level in levels:
        for points in (np.column_stack([ticks, np.full_like(ticks, level)]),   # X-path at Y = level
                       np.column_stack([np.full_like(ticks, level), ticks])):  # Y-path at X = level
            keep = _in_range(points, L1_mm, L2_mm, theta1_range, theta2_range)
            lines += _segments(points, keep, min_points)
    return _paths("grid paths", lines, L1_mm, L2_mm)


def random_commands(n: int, seed, theta1_range=PAPER_THETA1_RANGE, theta2_range=PAPER_THETA2_RANGE,
                    L1_mm: float = PAPER_L1_MM, L2_mm: float = PAPER_L2_MM) -> CommandSet:
    """``n`` random joint commands, uniform in the ranges (deg), random directions ±1 per axis.

    Unlike the campaign's grid (000 Eq. 11-12) these are off the map nodes, so
    they test the interpolation of Eq. (7)-(9) too. ``seed``: anything
    ``numpy.random.default_rng`` takes. Command positions use L1, L2 (mm).
    """
    rng = np.random.default_rng(seed)
    t1 = rng.uniform(*theta1_range, n)
    t2 = rng.uniform(*theta2_range, n)
    d = rng.choice([-1.0, 1.0], size=(n, 2))
    xy = forward_kinematics(t1, t2, L1_mm, L2_mm)[0]
    return CommandSet(f"{n} random commands", JointCommands(t1, t2, d[:, 0], d[:, 1]), xy, d[:, 0].copy(),
                      np.zeros(n, dtype=int))


# -- measurement, registration, comparison -------------------------------------------------------------
def measure(truth_robot, commands: JointCommands, spec: Optional[LaserTrackerSpec] = None, seed=0) -> np.ndarray:
    """Simulated laser-tracker readings (N, 2) mm of the robot's actual positions (000 §4.3).

    ``truth_robot``: a :class:`~olti_drake.model.scara.TrueRobot`; ``spec``: the
    tracker (default: AT960-XR of 000 §4.3); ``seed`` for the tracker noise.
    """
    p = truth_robot.end_effector(commands.theta1_deg, commands.theta2_deg, commands.dir1, commands.dir2)
    return measure_positions(p, spec or LaserTrackerSpec(), seed)


def _rms(e) -> float:
    """RMS length of error vectors (K, 2), mm; NaN when empty."""
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) if len(e) else float("nan")


def compare(models: Dict[str, ScaraModel], commands: JointCommands, measured, direction=None) -> dict:
    """Prediction errors of each model against the measured positions (000 Figs. 9-11).

    For each name -> model: predicted positions (Eq. 3 with Eq. 7 of 000),
    registered by :func:`register`, minus ``measured`` (N, 2) mm. Returns
    name -> {"rms_mm", "max_mm" (of the 2D error length), "rms_fwd_mm",
    "rms_rev_mm" (rows with ``direction`` +1 / -1; default dir1),
    "errors" (N, 2) mm, "predicted_mm" (N, 2) registered, "rotation_deg"}.
    """
    meas = np.asarray(measured, dtype=float)
    fwd = (commands.dir1 if direction is None else np.asarray(direction)) > 0
    out = {}
    for name, model in models.items():
        pred, angle = register(model.positions(commands), meas)
        e = pred - meas
        out[name] = {"rms_mm": _rms(e), "max_mm": float(np.max(np.hypot(*e.T))),
                     "rms_fwd_mm": _rms(e[fwd]), "rms_rev_mm": _rms(e[~fwd]),
                     "errors": e, "predicted_mm": pred, "rotation_deg": angle}
    return out


# -- the whole validation (shared by `olti demo` and examples/validate_paper_models.py) ---------------
def holding_map_ends(model: ScaraModel) -> ScaraModel:
    """The model with its maps holding their end values outside the grid (``outside="clamp"``).

    A controller using the map must do something beyond the calibrated range
    (the X = 200 mm path of 000 needs θ2* > 140°); holding the end value is the
    simplest choice. D-H models are returned unchanged.
    """
    if not model.is_errormap:
        return model
    return dataclasses.replace(model, map1=dataclasses.replace(model.map1, outside="clamp"),
                               map2=dataclasses.replace(model.map2, outside="clamp"))


def outside_map(model: ScaraModel, commands: JointCommands) -> np.ndarray:
    """Mask of commands outside the error map's grid on either axis (all False for D-H)."""
    if not model.is_errormap:
        return np.zeros(len(commands), dtype=bool)
    return np.any([(c < m.grid_deg[0] - 1e-9) | (c > m.grid_deg[-1] + 1e-9) for m, c in
                   ((model.map1, commands.theta1_deg), (model.map2, commands.theta2_deg))], axis=0)


def validation_sets(errormap_model: ScaraModel, L1_mm: float, L2_mm: float, n_random: int = 500,
                    seed=0) -> Dict[str, CommandSet]:
    """The three sets of 000 §4.3 for a robot with nominal L1, L2 (mm): X = 200 path, grid, random.

    Grid and random commands stay inside the identified map range (the grids
    of ``errormap_model``, deg); the X = 200 path is the paper's, as is.
    """
    r1 = tuple(errormap_model.map1.grid_deg[[0, -1]])
    r2 = tuple(errormap_model.map2.grid_deg[[0, -1]])
    return {"x200": x200_path(L1_mm, L2_mm), "grid": grid_paths(L1_mm, L2_mm, r1, r2),
            "random": random_commands(n_random, [seed, STREAM_RANDOM_COMMANDS], r1, r2, L1_mm, L2_mm)}


@dataclass
class SetResult:
    """One command set: its measured positions (N, 2) mm and :func:`compare`'s output."""

    commands: CommandSet
    measured_mm: np.ndarray
    comparison: dict
    n_outside_map: int


@dataclass
class ValidationReport:
    """Both identifications and their validation on unseen command sets (000 §4.2-4.3)."""

    identifications: dict
    results: Dict[str, SetResult] = field(default_factory=dict)
    tracker_std_mm: tuple = (0.0, 0.0)


def validate_models(data: CampaignData, truth_robot, nominal_mm=(PAPER_L1_MM, PAPER_L2_MM),
                    spec: Optional[LaserTrackerSpec] = None, seed=0, n_random: int = 500) -> ValidationReport:
    """Identify D-H and error-map models from ``data`` and validate them (000 §4.2-4.3).

    ``truth_robot``: the simulated robot (TrueRobot) the tracker measures;
    ``nominal_mm``: nominal (L1, L2) mm, the identification start and the
    controller's inverse kinematics; ``seed``: random commands and tracker
    noise. Returns a :class:`ValidationReport` keyed "D-H" and "error map".
    """
    from olti_drake.estimation.identification import IdentificationOptions, identify

    L1, L2 = nominal_mm
    idents = {label: identify(data, IdentificationOptions(model=kind, nominal_L1_mm=L1, nominal_L2_mm=L2))
              for label, kind in (("D-H", "dh"), ("error map", "errormap"))}
    models = {k: holding_map_ends(i.model) for k, i in idents.items()}
    spec = spec or LaserTrackerSpec()
    report = ValidationReport(idents)
    for k, (key, cs) in enumerate(validation_sets(idents["error map"].model, L1, L2, n_random, seed).items()):
        meas = measure(truth_robot, cs.commands, spec, [seed, STREAM_TRACKER, k])
        report.results[key] = SetResult(cs, meas, compare(models, cs.commands, meas, cs.pass_dir),
                                        int(outside_map(idents["error map"].model, cs.commands).sum()))
    u = np.concatenate([spec.std_mm(r.measured_mm) for r in report.results.values()])
    report.tracker_std_mm = (float(u.min()), float(u.max()))
    return report


def validation_table(report: ValidationReport) -> str:
    """Side-by-side prediction RMS / max (µm) of D-H vs error map on each set, and their ratio."""
    lines = ["validation on commands NOT used in the identification (000 §4.3); prediction - tracker reading",
             "after each model's best-fit rotation about J1 (the unobservable gauge); RMS and max of the 2D error:",
             f"  {'command set':28s} {'points':>6s}  {'D-H RMS / max, um':>18s}  "
             f"{'error map RMS / max, um':>23s}  {'RMS ratio':>9s}"]
    for label, (key, r) in zip("abc", report.results.items()):
        dh, em = r.comparison["D-H"], r.comparison["error map"]
        name = f"({label}) {r.commands.name}"
        lines.append(f"  {name:28s} {len(r.commands):6d}  {1e3 * dh['rms_mm']:8.1f} / {1e3 * dh['max_mm']:7.1f}  "
                     f"{1e3 * em['rms_mm']:13.1f} / {1e3 * em['max_mm']:7.1f}  "
                     f"{dh['rms_mm'] / em['rms_mm']:8.1f}x")
    lines.append(f"  tracker noise (simulated AT960-XR): {1e3 * report.tracker_std_mm[0]:.1f}.."
                 f"{1e3 * report.tracker_std_mm[1]:.1f} um per coordinate (k = 1)")
    rot = ", ".join(f"({label}) {1e3 * r.comparison['D-H']['rotation_deg']:.1f} / "
                    f"{1e3 * r.comparison['error map']['rotation_deg']:.1f}"
                    for label, r in zip("abc", report.results.values()))
    lines.append(f"  best-fit rotation about J1, D-H / error map, mdeg: {rot}")
    for label, r in zip("abc", report.results.values()):
        if r.n_outside_map:
            lines.append(f"  ({label}) {r.n_outside_map} of {len(r.commands)} commands lie outside the identified "
                         f"map range; there the error map holds its end values")
    return "\n".join(lines)


#: The files :func:`write_validation_figures` writes.
VALIDATION_FIGURES = ("fig6_maps.png", "fig9_10_x200.png", "fig11_error_vectors.png")


def write_validation_figures(report: ValidationReport, out_dir, truth=None) -> list:
    """Figs. 6, 9-10 and 11 of 000 for the report, as PNG files in ``out_dir``; returns the paths.

    ``truth``: the simulated robot (TrueRobot or campaign Setup) to overlay on
    Fig. 6, or None.
    """
    import os

    from olti_drake.report.figures import plot_error_vectors, plot_identified_maps, plot_path_deviation

    from olti_drake.io.outputs import make_dir

    make_dir(out_dir)
    x200, grid = report.results["x200"], report.results["grid"]
    fig6, fig9, fig11 = (os.path.join(out_dir, n) for n in VALIDATION_FIGURES)
    return [
        plot_identified_maps(report.identifications["error map"], truth, fig6),
        plot_path_deviation(x200.commands.xy_cmd_mm, x200.commands.pass_dir, x200.measured_mm,
                            x200.comparison["D-H"]["predicted_mm"], x200.comparison["error map"]["predicted_mm"],
                            fig9),
        plot_error_vectors(grid.commands.xy_cmd_mm, grid.commands.pass_dir, grid.commands.path_id,
                           grid.measured_mm, grid.comparison["error map"]["predicted_mm"],
                           grid.comparison["D-H"]["predicted_mm"], fig11),
    ]
