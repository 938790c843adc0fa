"""The machine-tool case of paper 001: an XY machine with volumetric errors, measured by an
"open-loop" tracking interferometer on a rotary table set at several positions.

Units: mm (µm in the error fields, as "thousandths of the command unit" of
:class:`~olti_drake.model.errormap.HarmonicDeviation`, which serves linear axes too).

* :class:`VolumetricError` -- E_XX, E_YY (linear positioning deviations),
  E_YX, E_XY (straightness) as smooth functions of the command, the squareness
  of Y to X; optionally bidirectional through the deviations' backlash terms.
* :func:`simulate_machine_campaign` -- every station position j, every target
  i: the rotary table turns the beam toward the *command* target from the
  *estimated* station (Eq. 1 of 001); the reading is the interferometer model
  of :mod:`olti_drake.model.instrument` (cosine error, beam loss, λ/64, budget
  noise: 001 Table 4).
* :func:`simulate_machine_campaign_3d` -- the same campaign in 3D (formats.md
  "Machine tool in 3D"): pan/tilt heads on the table aimed at the *commanded*
  tool point from the *estimated* head centre (001 Eq. 1 in 3D,
  :func:`~olti_drake.model.aiming3d.pan_tilt_commands`), the true tool points
  from a :func:`~olti_drake.model.volumetric3d.synthetic_truth` of the 21 error
  motions (smooth sines, in no fitted family), several tool mountings.
"""

from dataclasses import dataclass, field
from typing import Union

import numpy as np

from olti_drake.formats import result_header
from olti_drake.limits import check_allocation
from olti_drake.model.budget import paper001_budget
from olti_drake.model.errormap import Harmonic, HarmonicDeviation, NoDeviation, approach_directions
from olti_drake.model.instrument import InterferometerOptions, simulate_readings

Deviation = Union[HarmonicDeviation, NoDeviation]


# A few µm over 100 mm, like 001 Fig. 10: scale errors of tens of µm/m, pitch harmonics, straightness.
def _exx():
    return HarmonicDeviation(slope_mdeg_per_deg=0.06, harmonics=[Harmonic(3.0, 80.0, 20.0)])  # 60 µm/m + 3 µm


def _eyy():
    return HarmonicDeviation(slope_mdeg_per_deg=-0.04, harmonics=[Harmonic(2.5, 60.0, -50.0)])


def _eyx():
    return HarmonicDeviation(harmonics=[Harmonic(2.0, 150.0, 0.0)])


def _exy():
    return HarmonicDeviation(harmonics=[Harmonic(1.5, 120.0, 90.0)])


@dataclass
class VolumetricError:
    """2D volumetric error of an XY machine (ISO 230-1 names), µm over mm commands.

    Actual = command + (E_XX(x) + E_XY(y) − squareness·y, E_YY(y) + E_YX(x)):
    E_XX, E_YY positioning deviations of X and Y, E_YX straightness of X (a Y
    deviation along X), E_XY straightness of Y, squareness (µrad) of Y to X.
    """

    EXX: Deviation = field(default_factory=_exx)
    EYY: Deviation = field(default_factory=_eyy)
    EYX: Deviation = field(default_factory=_eyx)
    EXY: Deviation = field(default_factory=_exy)
    squareness_urad: float = 8.0

    def actual(self, commands_mm, dir_x=1.0, dir_y=1.0) -> np.ndarray:
        """Actual positions (N, 2) mm of the commands (N, 2) mm approached in (dir_x, dir_y)."""
        c = np.atleast_2d(np.asarray(commands_mm, dtype=float))
        x, y = c[:, 0], c[:, 1]
        dx = self.EXX(x, dir_x) + self.EXY(y, dir_y) - 1e-6 * self.squareness_urad * y
        dy = self.EYY(y, dir_y) + self.EYX(x, dir_x)
        return c + np.column_stack([dx, dy])


def square_targets(size_mm: float = 100.0, step_mm: float = 20.0, origin_mm=(0.0, 0.0), perimeter: bool = True):
    """Command target positions (N_i, 2) mm on a square grid; ``perimeter`` keeps its border only
    (001 §3.2: 20 positions, 20 mm steps, within 100 × 100 mm)."""
    if step_mm > 0:
        k = size_mm / step_mm
        check_allocation("step_mm", f"{step_mm:g} mm", [4 * k if perimeter else (k + 1) ** 2, 2],
                         what="coordinates (targets)", hint="use a coarser step_mm")
    n = int(round(size_mm / step_mm))
    ticks = np.arange(n + 1) * step_mm
    X, Y = np.meshgrid(ticks, ticks)
    keep = np.ones_like(X, dtype=bool)
    if perimeter:
        keep = (X == 0) | (Y == 0) | (X == ticks[-1]) | (Y == ticks[-1])
    return np.column_stack([X[keep], Y[keep]]) + np.asarray(origin_mm, dtype=float)


@dataclass
class MachineScenario:
    """A simulated 001 campaign: machine error, targets, station positions, estimates, instrument.

    ``station_estimate_sigma_um``: error of the rotation-centre estimate of
    001 §2.2 (11.5 µm at k = 2 in the paper); ``zero_angle_sigma_urad``: of the
    zero-angle alignment (u41). Defaults: the paper's experiment (Fig. 10).
    """

    error: VolumetricError = field(default_factory=VolumetricError)
    size_mm: float = 100.0
    step_mm: float = 20.0
    stations_mm: list[list[float]] = field(default_factory=lambda: [[-120.0, -80.0], [220.0, -60.0], [50.0, 240.0]])
    station_estimate_sigma_um: float = 5.75
    zero_angle_sigma_urad: float = 2.8
    stations_estimate_mm: list[list[float]] = field(default_factory=list)
    zero_angles_urad: list[float] = field(default_factory=list)
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    seed: int = 0


@dataclass
class MachineRun:
    """A machine campaign as executed: the (station, target) rows in order, and what the steering knows.

    Shared by the numpy twin and the Drake diagram, so both steer and zero
    their counters identically. mm, rad; directions ±1 per axis.
    """

    commands_mm: np.ndarray
    stations_mm: np.ndarray
    stations_estimate_mm: np.ndarray
    zero_angle_errors_rad: np.ndarray
    sequence: dict
    actual_mm: np.ndarray
    dead_paths_mm: np.ndarray

    @property
    def targets_mm(self) -> np.ndarray:
        """Actual position of every target at its first reading, (N_i, 2) mm."""
        first = [np.flatnonzero(self.sequence["target"] == i)[0] for i in range(len(self.commands_mm))]
        return self.actual_mm[first]


def machine_sequence(commands_mm, n_stations: int, dim: int = 2) -> dict:
    """Every (station, target) row in execution order: targets in order, once per station.

    Directions run over the whole campaign (station j's run starts where
    j − 1's ended), by the rule of formats.md. Returns dict of (K,) arrays:
    station, target (int), x_cmd_mm, y_cmd_mm (, z_cmd_mm), dir_x, dir_y (, dir_z) for ``dim`` = 2 (3).
    """
    cmd = np.asarray(commands_mm, dtype=float).reshape(-1, dim)
    i = np.tile(np.arange(len(cmd)), n_stations)
    d = approach_directions(cmd[i])
    out = {"station": np.repeat(np.arange(n_stations), len(cmd)), "target": i}
    out.update({f"{a}_cmd_mm": cmd[i, k] for k, a in enumerate("xyz"[:dim])})
    out.update({f"dir_{a}": d[:, k] for k, a in enumerate("xyz"[:dim])})
    return out


def machine_run(scenario: MachineScenario, rng: np.random.Generator) -> MachineRun:
    """Sequence, actual positions (bidirectional error applied), steering estimates and counter zeros.

    The station estimates and zero-angle errors are the scenario's own when
    given (e.g. from :mod:`olti_drake.estimation.station_estimation`), else drawn from
    ``rng`` (first P̂ − P, N_j × 2, then the zero angles, N_j). The counter of
    station j is zeroed at its first reading: L0_j is that distance (001 Eq. 3).
    """
    s = scenario
    if not (np.isfinite(s.size_mm) and np.isfinite(s.step_mm) and s.size_mm > 0 and s.step_mm > 0):
        raise ValueError(f"size_mm and step_mm must be finite and > 0, got {s.size_mm!r}, {s.step_mm!r}")
    P = np.asarray(s.stations_mm, dtype=float).reshape(-1, 2)
    if not len(P) or not np.all(np.isfinite(P)):
        raise ValueError(f"stations_mm must be a non-empty list of finite [x, y] pairs, got {s.stations_mm!r}")
    P_est = (np.asarray(s.stations_estimate_mm, dtype=float).reshape(-1, 2) if s.stations_estimate_mm else
             P + 1e-3 * s.station_estimate_sigma_um * rng.standard_normal(P.shape))
    delta = 1e-6 * (np.asarray(s.zero_angles_urad, dtype=float) if s.zero_angles_urad else
                    s.zero_angle_sigma_urad * rng.standard_normal(len(P)))
    if P_est.shape != P.shape or delta.shape != (len(P),):
        raise ValueError("stations_estimate_mm and zero_angles_urad must give one value per station")
    cmd = square_targets(s.size_mm, s.step_mm)
    seq = machine_sequence(cmd, len(P))
    actual = s.error.actual(cmd[seq["target"]], seq["dir_x"], seq["dir_y"])
    first = np.array([np.flatnonzero(seq["station"] == j)[0] for j in range(len(P))])
    return MachineRun(cmd, P, P_est, delta, seq, actual, np.hypot(*(actual[first] - P).T))


def simulate_machine_campaign(scenario: MachineScenario, budget=None):
    """Readings of every target from every station (001 §2, §3.2): (columns dict, truth dict).

    The numpy twin of the Drake diagram (:mod:`olti_drake.sim.machine_station`):
    the same :func:`machine_run`, the rotary table aiming by Eq. (1) of 001
    from the estimated station, the interferometer model of
    :func:`~olti_drake.model.instrument.simulate_readings`. Columns follow
    formats.md (station, target, x_cmd_mm, y_cmd_mm, displacement_mm, valid).
    """
    rng = np.random.default_rng(scenario.seed)
    run = machine_run(scenario, rng)
    seq, P, Pe = run.sequence, run.stations_mm, run.stations_estimate_mm
    i, j = seq["target"], seq["station"]
    cmd = run.commands_mm
    aim = np.degrees(np.arctan2(cmd[i, 1] - Pe[j, 1], cmd[i, 0] - Pe[j, 0]) + run.zero_angle_errors_rad[j])
    reading, valid, _ = simulate_readings(P[j], aim, run.actual_mm, run.dead_paths_mm[j], scenario.interferometer,
                                          budget or paper001_budget(), rng)
    cols = {"station": j, "target": i, "x_cmd_mm": cmd[i, 0], "y_cmd_mm": cmd[i, 1],
            "displacement_mm": np.where(valid, reading, np.nan), "valid": valid.astype(int)}
    truth = {**result_header("multilateration"), "targets_mm": run.targets_mm.tolist(), "stations_mm": P.tolist(),
             "dead_paths_mm": run.dead_paths_mm.tolist(), "commands_mm": cmd.tolist(),
             "gauge": "simulation truth: the machine's command frame", "residual_rms_mm": 0.0,
             "n_readings": int(valid.sum()), "stations_estimate_mm": Pe.tolist(), "seed": scenario.seed}
    return cols, truth


# ----------------------------------------------------------------------------- 3D
def _default_heads():
    # Five heads on the table around and below the default volumetric3d travel (tool 0 at z 100..350 mm),
    # at different heights: coplanar heads cannot calibrate themselves (multilateration refuses them).
    return [[-250.0, -200.0, -80.0], [650.0, -180.0, -150.0], [620.0, 520.0, -240.0], [-220.0, 480.0, -110.0],
            [200.0, 150.0, -320.0]]


@dataclass
class Machine3DScenario:
    """A simulated 3D campaign of the machine tool (formats.md "Machine tool in 3D"), mm, µm, µrad.

    ``config``: the machine (:class:`~olti_drake.model.volumetric3d.MachineConfig`: travel, tool offsets);
    the truth is ``synthetic_truth(config, truth_seed)``. Targets: a ``grid`` (nx, ny, nz) of commands
    over the travel, each once per tool of ``tools``: target i names one command and one tool.
    ``heads_mm``: the true pan/tilt centres; ``station_estimate_sigma_um`` and ``zero_angle_sigma_urad``:
    errors of their §2.2 estimates (centre, pan and tilt zeros); ``head_error_mdeg``: amplitude of the
    heads' own angular positioning error (:func:`~olti_drake.model.aiming3d.harmonic_head_error`).
    ``catseye_axis``: the reflector's axis (world; it faces the table). Seeded by ``seed``.
    """

    config: object = None
    grid: tuple = (5, 4, 3)
    tools: tuple = (0,)
    heads_mm: list = field(default_factory=_default_heads)
    station_estimate_sigma_um: float = 5.75
    zero_angle_sigma_urad: float = 2.8
    head_error_mdeg: float = 0.5
    catseye_axis: tuple = (0.0, 0.0, -1.0)
    truth_seed: int = 1
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    seed: int = 0


def grid_commands_3d(config, grid, tools=(0,)):
    """Commands (N, 3) mm on an nx × ny × nz grid over the travel, repeated per tool, and their tools (N,)."""
    from olti_drake.model.volumetric3d import AXES

    n = np.asarray(grid, dtype=int).reshape(3)
    if np.any(n < 2):
        raise ValueError(f"grid must have >= 2 points per axis, got {tuple(grid)!r}")
    check_allocation("grid", list(map(int, n)), [*map(float, n), len(tools), 3], what="coordinates (commands)",
                     hint="use fewer grid points")
    ticks = [np.linspace(*config.travel_mm[a], k) for a, k in zip(AXES, n)]
    pts = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    tools = np.asarray(tools, dtype=int)
    return np.tile(pts, (len(tools), 1)), np.repeat(tools, len(pts))


@dataclass
class Machine3DRun:
    """A 3D machine campaign as planned, shared by the numpy twin and the Drake diagram
    (:mod:`olti_drake.sim.machine3d_station`), so both aim, zero and read identically. mm, deg.

    ``commands_mm`` (N, 3) and ``tool`` (N,): target i; ``sequence``: :func:`machine_sequence` (dim 3);
    ``truth``: the volumetric3d motions; ``actual_mm`` (N, 3): the true tool point of each target;
    ``heads_true`` / ``heads_est``: centres and zeros, true and as estimated (001 §2.2);
    ``head_error``: the heads' angular positioning error (or None); ``dead_paths_mm`` (N_j,): L0_j,
    the distance from head j's true centre to the true tool point at its first reading (001 Eq. 3).
    ``rng``: the scenario's generator, drawn up to here (the twin's reading noise continues it).
    """

    config: object
    commands_mm: np.ndarray
    tool: np.ndarray
    sequence: dict
    truth: object
    actual_mm: np.ndarray
    heads_true: object
    heads_est: object
    head_error: object
    dead_paths_mm: np.ndarray
    rng: np.random.Generator

    @property
    def nominal_mm(self) -> np.ndarray:
        """The commanded tool points (N, 3) mm: command + the tool's nominal offset (what the heads aim at)."""
        return self.commands_mm + self.config.tools[self.tool]


def machine_run_3d(scenario: Machine3DScenario) -> Machine3DRun:
    """Draw the heads' zeros and estimates (seeded by ``scenario.seed``), the grid, the sequence, the
    true tool points and the counter zeros of a 3D campaign (:func:`simulate_machine_campaign_3d`)."""
    from olti_drake.model import aiming3d
    from olti_drake.model.volumetric3d import MachineConfig, synthetic_truth, tool_positions

    s = scenario
    config = s.config or MachineConfig()
    rng = np.random.default_rng(s.seed)
    P = np.asarray(s.heads_mm, dtype=float).reshape(-1, 3)
    zeros = rng.uniform(-180.0, 180.0, (len(P), 2)) * [1.0, 0.0]  # pan zero anywhere, tilt level
    P_est = P + 1e-3 * s.station_estimate_sigma_um * rng.standard_normal(P.shape)
    zeros_est = zeros - np.degrees(1e-6 * s.zero_angle_sigma_urad * rng.standard_normal(zeros.shape))
    cmd, tool = grid_commands_3d(config, s.grid, s.tools)
    seq = machine_sequence(cmd, len(P), dim=3)
    j = seq["station"]
    truth = synthetic_truth(config, s.truth_seed)
    actual = tool_positions(config, truth, cmd, tool)
    first = np.array([np.flatnonzero(j == k)[0] for k in range(len(P))])
    dead = np.hypot.reduce(actual[seq["target"][first]] - P, axis=1)
    err = aiming3d.harmonic_head_error(s.seed + 1, s.head_error_mdeg) if s.head_error_mdeg else None
    return Machine3DRun(config, cmd, tool, seq, truth, actual, aiming3d.PanTiltHeads(P, zeros),
                        aiming3d.PanTiltHeads(P_est, zeros_est), err, dead, rng)


def machine3d_truth(scenario: Machine3DScenario, run: Machine3DRun, n_readings: int) -> dict:
    """The simulated truth of a 3D campaign (multilateration result layout, formats.md)."""
    return {**result_header("multilateration"), "targets_mm": run.actual_mm.tolist(),
            "stations_mm": run.heads_true.centres_mm.tolist(), "dead_paths_mm": run.dead_paths_mm.tolist(),
            "commands_mm": run.commands_mm.tolist(), "tools": run.tool.tolist(),
            "tool_offsets_mm": run.config.tools.tolist(),
            "gauge": "simulation truth: the machine's command frame (workpiece side)", "residual_rms_mm": 0.0,
            "n_readings": int(n_readings), "stations_estimate_mm": run.heads_est.centres_mm.tolist(),
            "seed": scenario.seed, "truth_seed": scenario.truth_seed}


def simulate_machine_campaign_3d(scenario: Machine3DScenario, budget=None):
    """Readings of every target from every pan/tilt head (001 §2 in 3D): (columns dict, truth dict).

    Each head aims by 001 Eq. (1) in 3D at the COMMANDED tool point (command + the tool's nominal offset)
    from its ESTIMATED centre and zeros; the beam leaves the TRUE centre in the direction of the TRUE
    angles (zeros and the head's own error included) and reads the TRUE tool point (the volumetric3d
    truth), by :func:`~olti_drake.model.aiming3d.read_beam` (cosine error, beam loss, budget noise,
    λ/64). The counter of head j is zeroed at its first reading (L0_j, 001 Eq. 3). Columns follow
    formats.md (station, target, x/y/z_cmd_mm, tool, displacement_mm, valid). The numpy twin of the
    Drake diagram :mod:`olti_drake.sim.machine3d_station` (same :func:`machine_run_3d`).
    """
    from olti_drake.model import aiming3d

    s = scenario
    run = machine_run_3d(s)
    cmd, tool = run.commands_mm, run.tool
    i, j = run.sequence["target"], run.sequence["station"]
    angles = aiming3d.pan_tilt_commands(run.heads_est, j, run.nominal_mm[i])
    origin, u = aiming3d.pan_tilt_beam(run.heads_true, j, angles, run.head_error)
    beam = aiming3d.read_beam(origin, u, run.actual_mm[i], np.asarray(s.catseye_axis, float), run.dead_paths_mm[j],
                              s.interferometer, budget or paper001_budget(), run.rng,
                              pose_noise_on="origin")  # 001: the head's axis
    cols = {"station": j, "target": i, "x_cmd_mm": cmd[i, 0], "y_cmd_mm": cmd[i, 1], "z_cmd_mm": cmd[i, 2],
            "tool": tool[i], "displacement_mm": np.where(beam.valid, beam.reading_mm, np.nan),
            "valid": beam.valid.astype(int)}
    return cols, machine3d_truth(s, run, beam.valid.sum())
