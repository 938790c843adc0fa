"""Open-loop beam aiming in 3D for serial robots, and the initial estimates it starts from.

Two schemes (issue "Six-axis campaigns end to end", docs/six_axis_campaign.md):

* **Floor tracers** (001's scheme in 3D, the LaserTRACER layout): a cat's eye
  on the tool, a two-axis pan/tilt head at each station. The head aims from
  the *estimated* station centre (and its estimated zero angles) at the
  *commanded* tool point — 001 Eq. (1) in 3D: azimuth atan2(Δy, Δx), elevation
  atan2(Δz, √(Δx² + Δy²)) — and turns with its own angular positioning error.
  :func:`pan_tilt_commands`, :func:`pan_tilt_beam`, :func:`pan_tilt_readings`.
* **Robot-mounted interferometer** (000's scheme in 3D): the laser head is on
  the tool and the robot's own joints aim the beam at the *estimated* floor
  reflector: Drake ``InverseKinematics`` with the tool point at the commanded
  position and the reflector estimate on the beam line, nearest to the
  previous pose, within the joint limits, the roll about the beam free
  (:class:`RobotAimer`); :func:`robot_beam_readings` is the open-loop
  consequence on the true robot.

The reading of either (:func:`read_beam`): the interferometer returns the
optical length to the point of the beam nearest the cat's-eye centre,
(T − o)·u (the true distance times the cosine of the aiming error: cosine
error, 000 §5), minus the dead path; the beam is lost when it misses the
centre by more than the acceptance (``InterferometerOptions.acceptance_mm``,
1 mm in 000 §5) or arrives outside the cat's eye's ±80° viewing angle.

Initial estimates (the 3D counterparts of 000 Remark 1 / Eq. (2) and 001 §2.2):
:func:`search_reflector` (raster search maximizing the return signal, then the
least-squares intersection of the hitting beam lines) and
:func:`estimate_pan_tilt_station` (centre and zero angles fitted to the head
angles and distances at known commanded targets).

Robots are given as anything with ``chain``, ``chain_params`` (6N + 3) and
``actual_angles(commands, dirs)`` — :class:`~olti_drake.model.serial.SyntheticTruth`,
``SerialPositionModel.with_vector(x)``, or :class:`NominalRobot` (no errors).

Units: mm and degrees at every public function; SI only inside Drake's IK.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import numpy as np
from scipy.optimize import least_squares

from olti_drake.model.budget import Budget
from olti_drake.model.instrument import InterferometerOptions, quantize
from olti_drake.model.chain import DEG, SerialChain

#: Cat's-eye acceptance half-angle: beyond it the return beam is lost, deg.
MAX_VIEWING_DEG = 80.0
MM = 1e-3  # m per mm (Drake side)


# ------------------------------------------------------------------- robots
@dataclass(frozen=True, eq=False)
class NominalRobot:
    """A robot without errors: actual angles = commands, location errors as given (mm, deg)."""

    chain: SerialChain
    chain_params: np.ndarray

    def actual_angles(self, commands, dirs=None) -> np.ndarray:
        return np.atleast_2d(np.asarray(commands, float))


def nominal_robot(chain: SerialChain, tool_offset_mm=(0.0, 0.0, 0.0)) -> NominalRobot:
    """The nominal chain with the tool point at ``tool_offset_mm`` (tool frame, mm)."""
    return NominalRobot(chain, chain.nominal_parameters(tool_offset_mm))


def tool_frame_points(robot, commands, dirs, local_mm) -> np.ndarray:
    """World positions (M, K, 3) mm of K points fixed in the tool frame (``local_mm`` (K, 3), from
    the tool frame's origin) at the robot's actual angles for ``commands`` (M, N) deg.

    The chain model is affine in the tool offset t (p = o + R t, 000 Eq. (3) in 3D), so each
    point is one FK with t replaced — no orientation output is needed from the chain."""
    angles = robot.actual_angles(commands, dirs)
    n = robot.chain.n_joints
    params = np.array(robot.chain_params, float)
    out = []
    for point in np.atleast_2d(np.asarray(local_mm, float)):
        params[6 * n:] = point
        out.append(robot.chain.positions(angles, params))
    return np.stack(out, axis=1)


def tool_frame_line(robot, commands, dirs, origin_mm, direction) -> Tuple[np.ndarray, np.ndarray]:
    """A line fixed in the tool frame (origin mm, unit direction) in the world: (M, 3), (M, 3)."""
    origin = np.asarray(origin_mm, float)
    pts = tool_frame_points(robot, commands, dirs, np.vstack([origin, origin + _unit(direction)]))
    return pts[:, 0], pts[:, 1] - pts[:, 0]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(v)):
        raise ValueError("direction: must be a finite non-zero vector")
    return v / norm


# ------------------------------------------------------------------ reading
@dataclass(frozen=True)
class BeamReadings:
    """Per reading: ``reading_mm`` (optical length − dead path, cosine error in), ``valid``
    (beam returned), ``miss_mm`` (cat's-eye centre from the beam line), ``viewing_deg``
    (beam to the cat's-eye axis), ``along_mm`` ((T − o)·u)."""

    reading_mm: np.ndarray
    valid: np.ndarray
    miss_mm: np.ndarray
    viewing_deg: np.ndarray
    along_mm: np.ndarray


def beam_geometry_3d(origin_mm, u, target_mm) -> Tuple[np.ndarray, np.ndarray]:
    """(along, miss) mm: (T − o)·u and |(T − o) × u| — instrument.beam_geometry in 3D."""
    rel = np.asarray(target_mm, float) - np.asarray(origin_mm, float)
    along = np.einsum("mc,mc->m", rel, u)
    return along, np.linalg.norm(rel - along[:, None] * u, axis=1)


def viewing_angle_deg(u, catseye_axis) -> np.ndarray:
    """Angle (deg) between a cat's eye's axis (world, unit) and the direction back to the source, −u."""
    c = -np.einsum("mc,mc->m", u, np.broadcast_to(catseye_axis, u.shape))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def read_beam(origin_mm, u, target_mm, catseye_axis, dead_path_mm, options: InterferometerOptions,
              budget: Optional[Budget] = None, rng=None, pose_noise_on: str = "") -> BeamReadings:
    """What the interferometer reports for beams (origin, unit u) (M, 3) at cat's eyes ``target_mm``.

    Reading = (T − o)·u − d0 (``options.cosine_error``; else |T − o| − d0), plus the budget's
    noise (normal, seeded ``rng``, four normals per reading whatever is switched on): ``pose`` —
    a random 3D displacement (σ per coordinate, so its projection on the beam has σ, as in the
    2D model) of the element the moving axes carry, ``pose_noise_on`` = "target" (a cat's eye on a
    robot's tool) or "origin" (a laser on the robot, a head on a rotary table; "" = none) —
    and ``reading`` (along the beam); then λ/``resolution_divisor`` quantization, as switched in
    ``options`` (instrument.py's model, 000 §5). Invalid when the miss exceeds
    ``options.acceptance_mm`` or the viewing angle exceeds ±``MAX_VIEWING_DEG`` (``beam_loss``).
    """
    u = _unit(np.atleast_2d(u))
    origin = np.broadcast_to(np.asarray(origin_mm, float), u.shape)
    target = np.broadcast_to(np.asarray(target_mm, float), u.shape)
    noisy = options.noise and budget is not None
    z = np.random.default_rng(rng).standard_normal((len(u), 4)) if noisy else None
    if noisy and pose_noise_on:
        if pose_noise_on not in ("target", "origin"):
            raise ValueError(f"pose_noise_on: 'target', 'origin' or '', not {pose_noise_on!r}")
        shift = budget.combined("pose") * z[:, :3]
        if pose_noise_on == "target":
            target = target + shift
        else:
            origin = origin + shift
    along, miss = beam_geometry_3d(origin, u, target)
    view = viewing_angle_deg(u, _unit(catseye_axis))
    length = along if options.cosine_error else np.hypot(along, miss)
    reading = length - np.asarray(dead_path_mm, float)
    if noisy:
        reading = reading + budget.combined("reading") * z[:, 3]
    if options.quantization:
        reading = quantize(reading, options.resolution_mm)
    lost = (miss > options.acceptance_mm) | (view > MAX_VIEWING_DEG) | (along <= 0)
    valid = ~(options.beam_loss & lost)
    return BeamReadings(reading, valid, miss, view, along)


# ----------------------------------------------------------- pan/tilt heads
@dataclass(frozen=True)
class PanTiltHeads:
    """Two-axis heads: ``centres_mm`` (Nt, 3) the intersection of the pan and tilt axes (the beam
    passes through it), ``zeros_deg`` (Nt, 2): the beam's world azimuth at pan 0 and elevation at
    tilt 0 (the pan axis is the world z axis). Estimated or true, by use."""

    centres_mm: np.ndarray
    zeros_deg: np.ndarray

    def __post_init__(self):
        c = np.atleast_2d(np.asarray(self.centres_mm, float))
        z = np.zeros((len(c), 2)) if self.zeros_deg is None else np.atleast_2d(np.asarray(self.zeros_deg, float))
        if c.shape[1] != 3 or z.shape != (len(c), 2):
            raise ValueError(f"pan/tilt heads: centres (Nt, 3) and zeros (Nt, 2), got {c.shape}, {z.shape}")
        object.__setattr__(self, "centres_mm", c)
        object.__setattr__(self, "zeros_deg", z)


def azimuth_elevation_deg(from_mm, to_mm) -> Tuple[np.ndarray, np.ndarray]:
    """World azimuth atan2(Δy, Δx) and elevation atan2(Δz, √(Δx²+Δy²)) of to − from, deg
    (001 Eq. (1) in 3D; the azimuth alone is 001 Eq. (1))."""
    d = np.asarray(to_mm, float) - np.asarray(from_mm, float)
    return (np.degrees(np.arctan2(d[..., 1], d[..., 0])),
            np.degrees(np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))))


def pan_tilt_commands(heads_est: PanTiltHeads, station, commanded_mm) -> np.ndarray:
    """(M, 2) pan/tilt commands (deg) aiming each reading's head at the commanded tool point:
    the 3D 001 Eq. (1) from the ESTIMATED centre, minus the estimated zero angles."""
    st = np.asarray(station, int)
    az, el = azimuth_elevation_deg(heads_est.centres_mm[st], commanded_mm)
    return np.column_stack([az, el]) - heads_est.zeros_deg[st]


def pan_tilt_beam(heads_true: PanTiltHeads, station, commands_deg,
                  head_error: Optional[Callable] = None) -> Tuple[np.ndarray, np.ndarray]:
    """True beams (origins (M, 3) mm, unit directions (M, 3)) for pan/tilt commands (M, 2) deg:
    actual angles = command + ``head_error(commands) `` (M, 2) deg (the head's own angular
    positioning error), world angles = actual + true zeros, from the TRUE centre."""
    st = np.asarray(station, int)
    cmd = np.atleast_2d(np.asarray(commands_deg, float))
    actual = cmd + (head_error(cmd) if head_error is not None else 0.0)
    az, el = np.radians((actual + heads_true.zeros_deg[st]).T)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return heads_true.centres_mm[st], u


def harmonic_head_error(seed: int, amplitude_mdeg: float = 2.0) -> Callable:
    """A seeded angular positioning error of a pan/tilt head: per axis an offset-free first and
    second harmonic of its own angle, amplitudes up to ``amplitude_mdeg`` (mdeg). Returns
    f(commands (M, 2) deg) -> (M, 2) deg."""
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.3, 1.0, (2, 2)) * amplitude_mdeg * 1e-3
    phase = rng.uniform(0, 2 * np.pi, (2, 2))

    def error(commands_deg):
        c = np.radians(np.atleast_2d(np.asarray(commands_deg, float)))
        return sum(amp[h] * np.sin((h + 1) * c + phase[h]) for h in range(2))

    return error


def pan_tilt_readings(robot_true, commands, dirs, station, commanded_mm, heads_true: PanTiltHeads,
                      heads_est: PanTiltHeads, dead_paths_mm, *, catseye_axis_tool=(0.0, 0.0, 1.0),
                      head_error=None, options: Optional[InterferometerOptions] = None,
                      budget: Optional[Budget] = None, rng=None) -> BeamReadings:
    """Floor-tracer readings, vectorized over M readings: head j = ``station`` aims at the
    commanded tool point ``commanded_mm`` (M, 3) from its estimate; the true cat's eye is the
    true robot's tool point at ``commands`` (M, N)/``dirs``; its axis ``catseye_axis_tool`` is a
    direction in the tool frame (the true tool orientation)."""
    st = np.asarray(station, int)
    return head_readings(robot_true, commands, dirs, st, pan_tilt_commands(heads_est, st, commanded_mm), heads_true,
                         dead_paths_mm, catseye_axis_tool=catseye_axis_tool, head_error=head_error,
                         options=options, budget=budget, rng=rng)


def head_readings(robot_true, commands, dirs, station, head_commands_deg, heads_true: PanTiltHeads, dead_paths_mm, *,
                  catseye_axis_tool=(0.0, 0.0, 1.0), head_error=None, options: Optional[InterferometerOptions] = None,
                  budget: Optional[Budget] = None, rng=None) -> BeamReadings:
    """Floor-tracer readings for given pan/tilt commands (M, 2) deg (as a head's controller receives
    them): the true beam of head ``station`` (``pan_tilt_beam``) at the true cat's eye on the tool of
    ``robot_true`` at ``commands`` (M, N) / ``dirs``; ``dead_paths_mm`` indexed by station."""
    st = np.asarray(station, int)
    origin, u = pan_tilt_beam(heads_true, st, head_commands_deg, head_error)
    return _read_catseye_on_tool(robot_true, commands, dirs, origin, u, catseye_axis_tool,
                                 np.asarray(dead_paths_mm, float)[st], options, budget, rng)


def _read_catseye_on_tool(robot, commands, dirs, origin, u, axis_tool, dead, options, budget, rng):
    pts = tool_frame_points(robot, commands, dirs, np.vstack([np.zeros(3), _unit(axis_tool)]))
    centre = robot.chain.positions(robot.actual_angles(commands, dirs), robot.chain_params)
    return read_beam(origin, u, centre, pts[:, 1] - pts[:, 0], dead,
                     options or InterferometerOptions(), budget, rng, pose_noise_on="target")


# ------------------------------------------------------- robot-mounted laser
@dataclass(frozen=True)
class LaserOnTool:
    """The laser head on the tool: beam origin ``origin_mm`` and unit ``direction`` in the tool
    frame (from the tool frame's origin, mm). Scenario parameters."""

    origin_mm: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: Tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class AimResult:
    """``commands_deg`` (M, N) (NaN rows where not reached), ``success`` (M,), ``unreachable``
    (indices of the targets refused)."""

    commands_deg: np.ndarray
    success: np.ndarray

    @property
    def unreachable(self) -> np.ndarray:
        return np.flatnonzero(~self.success)


class RobotAimer:
    """Aims the robot-mounted beam at a floor reflector estimate by Drake ``InverseKinematics``.

    Per target: the tool point (``tool_offset_mm`` in the tool frame) at the commanded position
    within ±``position_tol_mm`` per axis (``AddPositionConstraint``, bounds at half of it), and
    the reflector estimate on the beam line: its position expressed in a beam frame (origin the laser origin, z along
    the beam; ``AddPositionConstraint`` with ``X_AbarA``) within ±``line_tol_mm`` laterally and
    ahead of the head. This is the gaze constraint of the issue in a form a solver meets to
    1e-6 mm: ``AddGazeTargetConstraint`` with a near-zero cone is quadratic in the angle, so its
    1e-6 feasibility tolerance leaves ~1e-3 rad. Joint limits from the model; cost ‖q − q_prev‖²
    (nearest to the previous pose, which also starts the solver); the roll about the beam is
    free. ``aim_beam=False`` drops the beam constraint: plain position-only IK (the benchmark's
    baseline; the reflector is then ignored). Nominal geometry (the plant's): the aim uses
    commands and estimates only (open loop).
    When SNOPT fails from the previous pose (a far first target), it restarts from up to
    ``restarts`` seeded random poses within the limits (cost still nearest to the previous pose);
    a target is refused (``success`` False) when no start gives a solution that, checked in the
    numpy model, meets every constraint within 10× its tolerance.
    """

    def __init__(self, chain: SerialChain, laser: LaserOnTool, tool_offset_mm=(0.0, 0.0, 0.0), *,
                 position_tol_mm: float = 1e-6, line_tol_mm: float = 1e-6, min_range_mm: float = 50.0,
                 restarts: int = 4, seed: int = 0, aim_beam: bool = True):
        from pydrake.solvers import SnoptSolver, SolverOptions

        self.chain, self.laser = chain, laser
        self.tool_offset = np.asarray(tool_offset_mm, float)
        self.position_tol, self.line_tol, self.min_range = position_tol_mm, line_tol_mm, min_range_mm
        self.restarts, self.seed, self.aim_beam = restarts, seed, aim_beam
        self.robot = nominal_robot(chain, self.tool_offset)
        self._solver = SnoptSolver()
        # the constraints are in metres: SNOPT's default 1e-6 feasibility would allow a micrometre
        self._options = SolverOptions()
        self._options.SetOption(self._solver.solver_id(), "Major feasibility tolerance", 1e-12)
        self._programs = {}

    def _program(self, reflector_mm):
        key = tuple(np.round(reflector_mm, 12))
        if key not in self._programs:
            self._programs[key] = self._build(np.asarray(reflector_mm, float))
        return self._programs[key]

    def _build(self, reflector_mm):
        from pydrake.math import RigidTransform, RotationMatrix
        from pydrake.multibody.inverse_kinematics import InverseKinematics

        plant = self.chain.plant
        tool = plant.get_frame(self.chain.tool_frame_index)
        world = plant.world_frame()
        ik = InverseKinematics(plant, True)
        big = np.full(3, 1e3)
        pos = ik.AddPositionConstraint(tool, self.tool_offset * MM, world, -big, big)
        beam_frame = RigidTransform(RotationMatrix.MakeFromOneVector(_unit(self.laser.direction), 2),
                                    np.asarray(self.laser.origin_mm, float) * MM)
        tol = 0.5 * self.line_tol * MM  # half: the solver's last digits stay inside the stated tolerance
        if self.aim_beam:
            ik.AddPositionConstraint(world, reflector_mm * MM, tool, beam_frame,
                                     np.array([-tol, -tol, self.min_range * MM]), np.array([tol, tol, 1e3]))
        n = plant.num_positions()
        cost = ik.prog().AddQuadraticErrorCost(np.eye(n), np.zeros(n), ik.q())
        return ik, pos, cost

    def aim(self, targets_mm, reflector_est_mm, q_start_deg) -> AimResult:
        """Joint commands (deg) aiming at the reflector estimate (3,) or (M, 3) mm from each
        commanded tool point (M, 3) mm, in order, each nearest to the previous solution
        (``q_start_deg`` (N,) before the first)."""
        targets = np.atleast_2d(np.asarray(targets_mm, float))
        refl = np.broadcast_to(np.asarray(reflector_est_mm, float), targets.shape)
        q_prev = np.radians(np.asarray(q_start_deg, float))
        if q_prev.shape != (self.chain.plant.num_positions(),):
            raise ValueError(f"q_start_deg: {q_prev.size} values, the plant has "
                             f"{self.chain.plant.num_positions()} positions")
        out = np.full((len(targets), self.chain.n_joints), np.nan)
        ok = np.zeros(len(targets), bool)
        order = self._plant_order()
        rng = np.random.default_rng(self.seed)
        for k, (target, reflector) in enumerate(zip(targets, refl)):
            ik, pos, cost = self._program(reflector)
            tol = 0.5 * self.position_tol * MM
            pos.evaluator().UpdateLowerBound(target * MM - tol)
            pos.evaluator().UpdateUpperBound(target * MM + tol)
            cost.evaluator().UpdateCoefficients(2 * np.eye(len(q_prev)), -2 * q_prev, q_prev @ q_prev)
            for guess in [q_prev] + [self._random_start(rng) for _ in range(self.restarts)]:
                result = self._solver.Solve(ik.prog(), guess, self._options)
                q = result.GetSolution(ik.q())
                cmd = np.degrees(q[order])
                if result.is_success() and self._satisfied(cmd, target, reflector):
                    out[k], ok[k], q_prev = cmd, True, q
                    break
        return AimResult(out, ok)

    def _random_start(self, rng):
        plant = self.chain.plant
        lo = np.maximum(plant.GetPositionLowerLimits(), -np.pi)
        hi = np.minimum(plant.GetPositionUpperLimits(), np.pi)
        return rng.uniform(lo, hi)

    def _plant_order(self):
        plant = self.chain.plant
        return np.array([plant.GetJointByName(j).position_start() for j in self.chain.joint_names])

    def _satisfied(self, cmd, target, reflector) -> bool:
        err = self.constraint_errors(cmd[None], target[None], reflector[None])
        return bool(err[0][0] <= 10 * self.position_tol and (err[1][0] <= 10 * self.line_tol or not self.aim_beam))

    def constraint_errors(self, commands_deg, targets_mm, reflector_mm):
        """(position error mm (max abs per axis), beam-line miss of the reflector mm, beam angle
        to the reflector rad) of commands in the numpy nominal model."""
        p = self.chain.positions(commands_deg, self.robot.chain_params)
        origin, u = tool_frame_line(self.robot, commands_deg, None, self.laser.origin_mm, self.laser.direction)
        along, miss = beam_geometry_3d(origin, u, reflector_mm)
        return np.abs(p - targets_mm).max(axis=1), miss, np.arctan2(miss, along)


def robot_beam_readings(robot_true, commands, dirs, laser: LaserOnTool, reflector_true_mm, dead_path_mm,
                        *, reflector_axis=(0.0, 0.0, 1.0), options: Optional[InterferometerOptions] = None,
                        budget: Optional[Budget] = None, rng=None) -> BeamReadings:
    """The open-loop consequence of robot-mounted aiming: the TRUE robot at ``commands`` (M, N)
    deg/``dirs`` carries the beam (laser origin and direction in its true tool frame); the floor
    cat's eye at ``reflector_true_mm`` (3,) or (M, 3), axis ``reflector_axis`` (world, default up)."""
    origin, u = tool_frame_line(robot_true, commands, dirs, laser.origin_mm, laser.direction)
    target = np.broadcast_to(np.asarray(reflector_true_mm, float), origin.shape)
    return read_beam(origin, u, target, _unit(reflector_axis), dead_path_mm,
                     options or InterferometerOptions(), budget, rng, pose_noise_on="origin")


# --------------------------------------------------- initial estimate: reflector
@dataclass(frozen=True)
class ReflectorSearch:
    """The search result: ``estimate_mm`` (3,), per search position the commands where the
    signal peaked (K, N) deg, the nominal beam lines there (origins, directions), and each
    line's distance from the estimate (mm). ``dilution``: √(K·λmax(A⁻¹)) for A = Σ(I − u uᵀ),
    the factor from a per-line lateral error to the estimate's error (≈ 1.2 for three
    orthogonal views, large when the lines are nearly parallel)."""

    estimate_mm: np.ndarray
    commands_deg: np.ndarray
    origins_mm: np.ndarray
    directions: np.ndarray
    line_residuals_mm: np.ndarray
    dilution: float


def intersect_lines(origins_mm, directions) -> np.ndarray:
    """Least-squares intersection of lines: argmin Σ |(I − u uᵀ)(P − o)|² (mm)."""
    u = _unit(directions)
    proj = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    a = proj.sum(axis=0)
    if np.linalg.cond(a) > 1e8:
        raise ValueError("reflector search: the hitting beam lines are (nearly) parallel; "
                         "use search positions that view the reflector from different directions")
    return np.linalg.solve(a, np.einsum("kij,kj->i", proj, origins_mm))


def search_reflector(robot_true, aimer: RobotAimer, search_points_mm, guess_mm, reflector_true_mm, q_start_deg,
                     *, reflector_axis=(0.0, 0.0, 1.0), search_radius_mm: float = 20.0,
                     fine_step_mm: float = 0.05, options: Optional[InterferometerOptions] = None,
                     seed: int = 0) -> ReflectorSearch:
    """000 Remark 1 / Eq. (2) in 3D, simulated: from each commanded tool point the robot aims at
    the rough ``guess_mm`` (nominal IK), then searches by moving the joints along the directions
    that shift the (nominal) beam sideways at the guess — a raster of step = acceptance over
    ±``search_radius_mm`` (a beam within the acceptance of the true reflector returns), then a fine
    raster of ``fine_step_mm`` (seeded phase) around the best coarse point, keeping the commands
    of the strongest return (Gaussian beam profile of 1/e² radius = acceptance on the TRUE robot).
    The reflector estimate is the least-squares intersection of the NOMINAL beam lines at those
    commands (the operator knows commands only). Raises ValueError naming the search position
    where nothing returns or IK fails."""
    options = options or InterferometerOptions()
    rng = np.random.default_rng(seed)
    guess = np.asarray(guess_mm, float)
    aimed = aimer.aim(search_points_mm, guess, q_start_deg)
    if len(aimed.unreachable):
        raise ValueError(f"reflector search: search position {aimed.unreachable[0]} cannot aim at the guess")
    acc = options.acceptance_mm
    coarse = _raster(search_radius_mm, acc, rng)
    fine = _raster(acc, fine_step_mm, rng)
    found = []
    for k, q0 in enumerate(aimed.commands_deg):
        jac = _lateral_jacobian(aimer, q0, guess)
        best, signal = _best_raster(robot_true, aimer.laser, q0, jac, coarse, reflector_true_mm, reflector_axis, acc)
        if signal <= 0:
            raise ValueError(f"reflector search: no return at search position {k} within "
                             f"{search_radius_mm:g} mm of the guess")
        q_best, _ = _best_raster(robot_true, aimer.laser, best, jac, fine, reflector_true_mm, reflector_axis, acc)
        found.append(q_best)
    found = np.array(found)
    origins, u = tool_frame_line(aimer.robot, found, None, aimer.laser.origin_mm, aimer.laser.direction)
    estimate = intersect_lines(origins, u)
    _, miss = beam_geometry_3d(origins, u, np.broadcast_to(estimate, origins.shape))
    a = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]).sum(axis=0)
    dilution = float(np.sqrt(len(u) * np.linalg.eigvalsh(np.linalg.inv(a)).max()))
    return ReflectorSearch(estimate, found, origins, u, miss, dilution)


def _raster(radius_mm, step_mm, rng) -> np.ndarray:
    """Square raster (K, 2) mm of ``step_mm`` over ±``radius_mm``, with a seeded phase."""
    n = int(np.ceil(radius_mm / step_mm))
    g = (np.arange(-n, n + 1) + rng.uniform(-0.5, 0.5)) * step_mm
    a, b = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([a.ravel(), b.ravel()])


def _lateral_jacobian(aimer, q0, point, h_deg=1e-4) -> np.ndarray:
    """(N, 2): joint moves (deg) that shift the nominal beam 1 mm sideways at ``point`` along two
    directions normal to the beam (minimum-norm pseudo-inverse of the central-difference map)."""
    o0, u0 = tool_frame_line(aimer.robot, q0[None], None, aimer.laser.origin_mm, aimer.laser.direction)
    e1 = np.cross(u0[0], [0.0, 0.0, 1.0] if abs(u0[0, 2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u0[0], e1)
    steps = np.vstack([q0 + h_deg * np.eye(len(q0)), q0 - h_deg * np.eye(len(q0))])
    o, u = tool_frame_line(aimer.robot, steps, None, aimer.laser.origin_mm, aimer.laser.direction)
    rel = point - o
    foot = o + np.einsum("mc,mc->m", rel, u)[:, None] * u - point  # beam's nearest point, from the point
    lateral = np.column_stack([foot @ e1, foot @ e2])
    n = len(q0)
    jac = (lateral[:n] - lateral[n:]) / (2 * h_deg)  # (N, 2) mm/deg
    return np.linalg.pinv(jac.T)


def _best_raster(robot_true, laser, q0, jac, raster, reflector, axis, acc):
    """Commands of the raster point with the strongest return on the true robot, and that signal."""
    cmds = q0 + raster @ jac.T
    origin, u = tool_frame_line(robot_true, cmds, None, laser.origin_mm, laser.direction)
    along, miss = beam_geometry_3d(origin, u, np.broadcast_to(reflector, origin.shape))
    view = viewing_angle_deg(u, _unit(axis))
    signal = np.where((miss <= acc) & (view <= MAX_VIEWING_DEG) & (along > 0), np.exp(-2 * (miss / acc) ** 2), 0.0)
    k = int(np.argmax(signal))
    return cmds[k], float(signal[k])


# ------------------------------------------------- initial estimate: pan/tilt head
@dataclass(frozen=True)
class StationEstimate:
    """A pan/tilt station fitted by :func:`estimate_pan_tilt_station`: centre (3,) mm, zeros (2,)
    deg, dead path mm, residual RMS (mm), the head angles and readings used."""

    centre_mm: np.ndarray
    zeros_deg: np.ndarray
    dead_path_mm: float
    rms_mm: float
    angles_deg: np.ndarray
    readings_mm: np.ndarray


def estimate_pan_tilt_station(robot_true, commands, dirs, commanded_mm, head_true: PanTiltHeads, guess: PanTiltHeads,
                              dead_path_mm: float, *, catseye_axis_tool=(0.0, 0.0, 1.0), head_error=None,
                              search_step_deg: float = 1e-3, options: Optional[InterferometerOptions] = None,
                              budget: Optional[Budget] = None, seed: int = 0) -> StationEstimate:
    """001 §2.2 in 3D, simulated: the robot puts the cat's eye at K known commanded points
    (``commands`` (K, N), ``commanded_mm`` (K, 3)); at each the head is turned until the return
    peaks (its pan/tilt commands, on a grid of ``search_step_deg`` with a seeded phase, through its
    own ``head_error``) and the interferometer reads. The centre, zero angles and dead path are the
    least squares of r_angle = (θ_k + zero − 001 Eq. (1) in 3D from C to the commanded point) · ρ_k
    (mm) and r_dist = |T*_k − C| − d0 − reading_k. Refuses (ValueError) a non-converged fit or a
    search position where the beam does not return. ``head_true`` holds one head."""
    options = options or InterferometerOptions()
    rng = np.random.default_rng(seed)
    targets = np.atleast_2d(np.asarray(commanded_mm, float))
    true_centre = robot_true.chain.positions(robot_true.actual_angles(commands, dirs), robot_true.chain_params)
    st = np.zeros(len(targets), int)
    wanted = pan_tilt_commands(head_true, st, true_centre)  # world angles to the true cat's eye − true zeros
    cmd = wanted.copy()
    for _ in range(5):  # the head settles where its actual angle is the wanted one
        cmd = wanted - (head_error(cmd) if head_error is not None else 0.0)
    phase = rng.uniform(-0.5, 0.5, 2) * search_step_deg
    cmd = np.round((cmd - phase) / search_step_deg) * search_step_deg + phase
    origin, u = pan_tilt_beam(head_true, st, cmd, head_error)
    reads = _read_catseye_on_tool(robot_true, commands, dirs, origin, u, catseye_axis_tool,
                                  np.full(len(targets), dead_path_mm), options, budget, rng)
    if not np.all(reads.valid):
        raise ValueError(f"pan/tilt station estimate: no return at target {np.flatnonzero(~reads.valid)[0]}")
    x0 = np.concatenate([guess.centres_mm[0], guess.zeros_deg[0], [0.0]])
    fit = least_squares(_station_residuals, x0, args=(targets, cmd, reads.reading_mm), method="lm", xtol=1e-14)
    if not fit.success:
        raise ValueError(f"pan/tilt station estimate: the fit did not converge ({fit.message})")
    rms = float(np.sqrt(np.mean(fit.fun ** 2)))
    return StationEstimate(fit.x[:3], fit.x[3:5], float(fit.x[5]), rms, cmd, reads.reading_mm)


def _station_residuals(x, targets, angles, readings):
    centre, zeros, d0 = x[:3], x[3:5], x[5]
    az, el = azimuth_elevation_deg(centre, targets)
    rho = np.linalg.norm(targets - centre, axis=1)
    d_az = (angles[:, 0] + zeros[0] - az + 180.0) % 360.0 - 180.0
    d_el = angles[:, 1] + zeros[1] - el
    return np.concatenate([d_az * DEG * rho * np.cos(np.radians(el)), d_el * DEG * rho, rho - d0 - readings])
