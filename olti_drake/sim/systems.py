"""Drake systems of the open-loop tracking interferometer campaign (paper 000 §2).

Thin ``LeafSystem`` wrappers over the numpy modules (error map, steering,
interferometer), so the simulation and the identifier share one model.

Ports carry **SI units** as Drake's MultibodyPlant does: joint angles in rad,
J3 stroke and the displacement in m. Files and the CLI stay in mm/deg; the
conversion happens at these ports only.

One clock drives a campaign: every ``period_s`` the :class:`PlanSequencer`
steps to the next plan row (move), and half a period later the
:class:`CampaignRecorder` takes the reading (settle, read).
"""

from __future__ import annotations

import re
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.systems.framework import BasicVector, BasicVector_, LeafSystem, LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem

from olti_drake.io.budget import Budget
from olti_drake.model.errormap import ErrorMap, approach_directions
from olti_drake.model.instrument import InterferometerOptions, simulate_readings
from olti_drake.model.instrument import beam_command_deg

M_TO_MM = 1e3


class ReadStatus(NamedTuple):
    """How one interferometer reading was obtained (the stations' abstract ``status`` output).

    ``raw``: the counter's raw status, logged and never interpreted (docs/protocol.md READ; the
    simulated counter uses the emulator's register: ``0000`` good, ``8001`` no beam); ``reads``:
    READ requests made for this reading (1 + re-reads); ``rezeros``: counter re-zeroings at the
    run's reference pose made for it (the beam-loss policy, :mod:`olti_drake.hardware.station`).
    """

    raw: str = ""
    reads: int = 0
    rezeros: int = 0


def set_default_name(system) -> None:
    """Name a system after its class, snake_case (``ErrorMapJoint`` -> ``error_map_joint``).

    Every system of the package calls this in its constructor, so a diagram reads the same
    whether a builder used ``AddSystem`` or ``AddNamedSystem``. A scalar-type template's
    instantiation (``ErrorMapJoint_[AutoDiffXd]``) is named after its template.
    """
    name = type(system).__name__.split("_\U0001d4e3")[0]  # TemplateSystem instantiations: Name_𝓣T𝓤
    system.set_name(re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower())


def _deg_mm(values, revolute):
    """Port values (rad, m) -> (deg, mm), per axis; float or AutoDiffXd (object) arrays."""
    values = np.asarray(values)
    if values.dtype == object:
        return values * np.where(revolute, 180.0 / np.pi, M_TO_MM)
    return np.where(revolute, np.degrees(values), values * M_TO_MM)


def _si(values, revolute):
    """(deg, mm) -> port values (rad, m), per axis; float or AutoDiffXd (object) arrays."""
    values = np.asarray(values)
    if values.dtype == object:
        return values * np.where(revolute, np.pi / 180.0, 1.0 / M_TO_MM)
    return np.where(revolute, np.radians(values), values / M_TO_MM)


def _value(values) -> np.ndarray:
    """The float values of a float or AutoDiffXd array (derivatives dropped)."""
    values = np.asarray(values)
    if values.dtype != object:
        return values.astype(float)
    return np.array([v.value() if hasattr(v, "value") else float(v) for v in values.ravel()]).reshape(values.shape)


class _ApproachError:
    """The approach-direction bookkeeping of :class:`ApproachErrorSystem` for any scalar type.

    Input ``command`` (n): commanded positions (rad for revolute axes, m
    otherwise). State: the last command and the approach direction of every
    axis, updated every simulator step by the spec's rule (an axis that did
    not move keeps its direction). Outputs ``position`` (n): the actual
    positions; ``direction`` (n): ±1. Outputs combine the stored state with
    the *current* input, so they are right at the instant a command changes,
    whatever the event ordering. Directions are decided on values (they are
    ±1, not differentiable); positions keep the command's derivatives.
    """

    def _declare_approach(self, revolute: Sequence[bool], initial_direction: float, T=float):
        self._revolute = np.asarray(revolute, dtype=bool)
        self._initial_direction, self._T = float(initial_direction), T
        n = self._n = len(self._revolute)
        self.DeclareVectorInputPort("command", n)
        self.DeclareDiscreteState(np.concatenate([np.full(n, np.nan), np.full(n, initial_direction)]))
        self.DeclarePerStepDiscreteUpdateEvent(self._remember)
        self.DeclareVectorOutputPort("position", n, self._calc_position)
        self.DeclareVectorOutputPort("direction", n, self._calc_direction)

    def actual(self, command, direction) -> np.ndarray:
        """Actual positions (n,) deg/mm of ``command`` (n,) deg/mm approached in ``direction`` (n,)."""
        raise NotImplementedError

    def _actual(self, context, command, direction):
        return self.actual(command, direction)

    def _command_and_direction(self, context):
        cmd = _deg_mm(self.get_input_port(0).Eval(context), self._revolute)
        s = _value(context.get_discrete_state_vector().CopyToVector())
        return cmd, approach_directions(_value(cmd)[None], s[:self._n], s[self._n:])[0]

    def _remember(self, context, discrete_state):
        cmd, direction = self._command_and_direction(context)
        discrete_state.set_value(np.array([self._T(v) for v in np.concatenate([_value(cmd), direction])],
                                          dtype=object if self._T is not float else float))

    def _calc_direction(self, context, output):
        output.SetFromVector(self._command_and_direction(context)[1])

    def _calc_position(self, context, output):
        cmd, direction = self._command_and_direction(context)
        output.SetFromVector(_si(self._actual(context, cmd, direction), self._revolute))


class ApproachErrorSystem(_ApproachError, LeafSystem):
    """Commanded -> actual positions through an error model that depends on the approach direction.

    Ports and state as :class:`_ApproachError`; subclasses give :meth:`actual` in deg/mm.
    """

    def __init__(self, revolute: Sequence[bool], initial_direction: float = 1.0):
        LeafSystem.__init__(self)
        set_default_name(self)
        self._declare_approach(revolute, initial_direction)


@TemplateSystem.define("ErrorMapJoint_", T_list=(float, AutoDiffXd))
def ErrorMapJoint_(T):
    """ErrorMapJoint for scalar type T (float or AutoDiffXd): ``ErrorMapJoint_[T]``.

    Not symbolic: the interpolation picks nodes by the command's value (a Diagram would
    otherwise try ``Expression`` to find its feedthrough).
    """

    class Impl(_ApproachError, LeafSystem_[T]):
        """Commanded -> actual joint angles through the error map, θ = θ* + Δθ(θ*, dir) (000 Eq. 7).

        One deviation per axis (an :class:`~olti_drake.model.errormap.ErrorMap`, a
        continuous truth, or None for a perfect axis); ports as
        :class:`ApproachErrorSystem`. The node values of every ``ErrorMap`` axis are a
        numeric Parameter of the Context, [forward..., reverse...] deg (Eq. 6 order;
        default: the map's): :meth:`SetMapValues` / :meth:`GetMapValues`. With
        ``ToAutoDiffXd()`` a reading is differentiable with respect to them; the
        interpolation weights (Eq. 9) are taken at the command's value (the map's
        slope in θ* is not carried), a continuous truth adds a constant.
        """

        def _construct(self, deviations, revolute, initial_direction=1.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._dev = list(deviations)
            self._declare_approach(revolute, initial_direction, T)
            self._maps = {i: self.DeclareNumericParameter(BasicVector_[T](dev.values.tolist()))
                          for i, dev in enumerate(self._dev) if isinstance(dev, ErrorMap)}

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._dev, other._revolute, other._initial_direction, converter=converter)

        def SetMapValues(self, context, axis: int, values_deg) -> None:
            """Set axis ``axis``'s node values (2N,) deg, [forward..., reverse...], in ``context``."""
            context.get_mutable_numeric_parameter(self._maps[axis]).SetFromVector(values_deg)

        def GetMapValues(self, context, axis: int) -> np.ndarray:
            """Axis ``axis``'s node values (2N,) deg in ``context``."""
            return context.get_numeric_parameter(self._maps[axis]).CopyToVector()

        def _actual(self, context, command, direction):
            out = command.copy()
            for i, dev in enumerate(self._dev):
                if dev is None:
                    continue
                theta = _value(command[i:i + 1])
                if i in self._maps:
                    (c0, c1), (w0, w1) = (x[0] for x in dev.interpolation(theta, direction[i:i + 1]))
                    v = self.GetMapValues(context, i)
                    out[i] = out[i] + (w0 * v[c0] + w1 * v[c1])
                else:
                    out[i] = out[i] + dev(theta, direction[i:i + 1])[0]
            return out

    return Impl


ErrorMapJoint = ErrorMapJoint_[None]


class BeamSteering(LeafSystem):
    """Open-loop J4 command toward the *estimated* reflector (000 Eq. 1).

    Inputs ``arm_command`` (2): θ1*, θ2* (rad); ``reflector`` (1): index j.
    Output ``joint_command`` (4): θ1*, θ2*, J3 stroke (m), θ4* (rad).
    Uses the nominal link lengths (mm) -- the command position -- and the
    estimates of the reflector positions (mm) and θ40 (deg); the estimates are a
    numeric Parameter of the Context [P0x, P0y, P1x, ..., θ40] (default: the
    constructor's): :meth:`SetReflectorEstimates` / :meth:`GetReflectorEstimates`.
    """

    def __init__(self, L1_mm: float, L2_mm: float, reflectors_estimate_mm, theta40_estimate_deg: float,
                 stroke_m: float = 0.0):
        super().__init__()
        set_default_name(self)
        self._L = (L1_mm, L2_mm)
        P = np.asarray(reflectors_estimate_mm, dtype=float).reshape(-1, 2)
        self._estimates = self.DeclareNumericParameter(BasicVector(np.append(P.ravel(), theta40_estimate_deg)))
        self._stroke = stroke_m
        self.DeclareVectorInputPort("arm_command", 2)
        self.DeclareVectorInputPort("reflector", 1)
        self.DeclareVectorOutputPort("joint_command", 4, self._calc)

    def SetReflectorEstimates(self, context, reflectors_mm, theta40_deg: float) -> None:
        """Set the estimated reflector positions (Nt, 2) mm and θ40 (deg) used in ``context``."""
        context.get_mutable_numeric_parameter(self._estimates).SetFromVector(
            np.append(np.asarray(reflectors_mm, dtype=float).ravel(), theta40_deg))

    def GetReflectorEstimates(self, context):
        """(reflectors (Nt, 2) mm, θ40 deg) used in ``context``."""
        v = context.get_numeric_parameter(self._estimates).CopyToVector()
        return v[:-1].reshape(-1, 2), float(v[-1])

    def _calc(self, context, output: BasicVector):
        t1, t2 = np.degrees(self.get_input_port(0).Eval(context))
        j = int(self.get_input_port(1).Eval(context)[0])
        P, theta40 = self.GetReflectorEstimates(context)
        t4 = beam_command_deg(t1, t2, P[j], *self._L, theta40)
        output.SetFromVector([np.radians(t1), np.radians(t2), self._stroke, np.radians(float(np.ravel(t4)[0]))])


class LaserInterferometer(LeafSystem):
    """The laser range sensor on J4 (000 §2, §5; Table 2 noise).

    Inputs ``geometry_query`` (QueryObject of the SceneGraph holding the
    robot: the laser head pose comes from the flange body's pose, the
    reflector centres from the reflector bodies') and ``reflector`` (1):
    index j of the reflector in use.
    Outputs ``displacement`` (1, m): reading with the counter zero at
    ``dead_paths_mm[j]``; ``valid`` (1): 0 when the beam misses the cat's eye
    centre by more than the acceptance; ``miss`` (1, m): that miss.

    Noise is a deterministic function of (seed, sample count): the count is a
    discrete state stepped every ``period_s``, so re-evaluating a port gives
    the same reading and the same seed gives the same campaign. The dead paths
    (mm) are a numeric Parameter of the Context (default: the constructor's):
    :meth:`SetDeadPaths` / :meth:`GetDeadPaths`.
    """

    def __init__(self, flange_frame_id, X_FL, reflector_frame_ids, dead_paths_mm,
                 options: InterferometerOptions, budget: Budget, seed: int, period_s: float):
        super().__init__()
        set_default_name(self)
        self._frame = flange_frame_id
        self._X_FL = X_FL
        self._reflectors = list(reflector_frame_ids)
        self._dead_paths = self.DeclareNumericParameter(BasicVector(np.asarray(dead_paths_mm, dtype=float)))
        self._options, self._budget, self._seed = options, budget, int(seed)
        self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.DeclareVectorInputPort("reflector", 1)
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._count)
        self._reading = self.DeclareCacheEntry(
            "reading", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(3)), calc=self._calc),
            {self.all_sources_ticket()})
        for i, name in enumerate(("displacement", "valid", "miss")):
            self.DeclareVectorOutputPort(name, 1, lambda c, o, i=i: o.SetAtIndex(0, self._reading.Eval(c)[i]))
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make(ReadStatus()), self._calc_status)

    def SetDeadPaths(self, context, dead_paths_mm) -> None:
        """Set the counter zero d0_j (mm) of every reflector's run in ``context`` (000 Eq. 5)."""
        context.get_mutable_numeric_parameter(self._dead_paths).SetFromVector(dead_paths_mm)

    def GetDeadPaths(self, context) -> np.ndarray:
        """The dead paths d0_j (mm) used in ``context``."""
        return context.get_numeric_parameter(self._dead_paths).CopyToVector()

    def _calc_status(self, context, value):
        valid = self._reading.Eval(context)[1] > 0.5
        value.set_value(ReadStatus("0000" if valid else "8001", 1, 0))

    def _count(self, context, discrete_state):
        discrete_state.set_value([context.get_discrete_state_vector()[0] + 1])

    def _calc(self, context, value):
        query = self.get_input_port(0).Eval(context)
        X_WL = query.GetPoseInWorld(self._frame) @ self._X_FL
        j = int(self.get_input_port(1).Eval(context)[0])
        P = query.GetPoseInWorld(self._reflectors[j]).translation()[:2] * M_TO_MM
        origin = X_WL.translation()[:2] * M_TO_MM
        x_axis = X_WL.rotation().matrix()[:2, 0]
        angle = np.degrees(np.arctan2(x_axis[1], x_axis[0]))
        rng = np.random.default_rng([self._seed, int(context.get_discrete_state_vector()[0])])
        reading, valid, miss = simulate_readings(origin[None], [angle], P[None], [self.GetDeadPaths(context)[j]],
                                                 self._options, self._budget, rng)
        value.set_value(np.array([reading[0] / M_TO_MM, float(valid[0]), miss[0] / M_TO_MM]))


@TemplateSystem.define("KinematicLaserInterferometer_", T_list=(float, AutoDiffXd))
def KinematicLaserInterferometer_(T):
    """KinematicLaserInterferometer for scalar type T (float or AutoDiffXd).

    Not symbolic: noise, quantization and beam loss are decided on values.
    """

    class Impl(LeafSystem_[T]):
        """The laser range sensor of :class:`LaserInterferometer` without SceneGraph (000 §2, §5).

        Input ``position`` (nq): the plant's positions q (SI, plant order) -- the actual joints, e.g.
        :class:`ErrorMapJoint`'s ``position``; ``reflector`` (1): index j. Outputs, ports and noise
        as :class:`LaserInterferometer`. The laser head pose comes from the plant's own kinematics
        in T (``plant`` converted with ``ToAutoDiffXd()`` for T = AutoDiffXd), so the whole station
        converts with ``Diagram.ToAutoDiffXd()`` and a reading is differentiable with respect to q
        and what feeds it (the map nodes of :class:`ErrorMapJoint`; the dead paths, a Parameter).

        The reading's value is :func:`~olti_drake.model.instrument.simulate_readings` of the
        float pose (noise, quantization, cosine error as the options say), so it equals the
        geometry station's; its derivatives are those of the exact optical length (the beam
        projection ``(P - o)·u`` with the cosine error, ``‖P - o‖`` without) minus d0_j: noise and
        quantization are constants of the pose. ``reflectors_mm`` (Nt, 2): the true reflector
        centres, mm (fixed in the world); ``laser_head``: name of the plant frame whose +x is the beam.
        """

        def _construct(self, plant, reflectors_mm, dead_paths_mm, options: InterferometerOptions, budget: Budget,
                       seed: int, period_s: float, laser_head: str = "laser_head", converter=None):
            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._args = (plant, reflectors_mm, dead_paths_mm, options, budget, seed, period_s, laser_head)
            self._plant = plant if T is float else plant.ToAutoDiffXd()   # the plant in this scalar type
            self._head = self._plant.GetFrameByName(laser_head)
            self._P = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)
            self._options, self._budget, self._seed = options, budget, int(seed)
            self._dead_paths = self.DeclareNumericParameter(
                BasicVector_[T](np.asarray(dead_paths_mm, dtype=float).tolist()))
            position = self.DeclareVectorInputPort("position", plant.num_positions())
            self.DeclareVectorInputPort("reflector", 1)
            # A context of the plant at the input positions, cached in this system's Context (one per Context).
            self._plant_context = self.DeclareCacheEntry(
                "plant_context", ValueProducer(
                    allocate=lambda: AbstractValue.Make(self._plant.CreateDefaultContext()),
                    calc=self._calc_plant_context), {position.ticket()})
            self.DeclareDiscreteState(1)
            self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._count)
            self._reading = self.DeclareCacheEntry(
                "reading", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(3, dtype=object)),
                                         calc=self._calc), {self.all_sources_ticket()})
            for i, name in enumerate(("displacement", "valid", "miss")):
                self.DeclareVectorOutputPort(name, 1, lambda c, o, i=i: o.SetAtIndex(0, self._reading.Eval(c)[i]))
            self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make(ReadStatus()), self._calc_status)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, *other._args, converter=converter)

        def SetDeadPaths(self, context, dead_paths_mm) -> None:
            """Set the counter zero d0_j (mm) of every reflector's run in ``context`` (000 Eq. 5)."""
            context.get_mutable_numeric_parameter(self._dead_paths).SetFromVector(dead_paths_mm)

        def GetDeadPaths(self, context) -> np.ndarray:
            """The dead paths d0_j (mm) used in ``context``."""
            return context.get_numeric_parameter(self._dead_paths).CopyToVector()

        def _calc_status(self, context, value):
            valid = _value(self._reading.Eval(context)[1:2])[0] > 0.5
            value.set_value(ReadStatus("0000" if valid else "8001", 1, 0))

        def _count(self, context, discrete_state):
            discrete_state.set_value([context.get_discrete_state_vector()[0] + 1])

        def _calc_plant_context(self, context, value):
            self._plant.SetPositions(value.get_mutable_value(), self.get_input_port(0).Eval(context))

        def _beam(self, context):
            """Beam origin (2,) mm and direction (2,) of the laser head at the input positions, in T."""
            X_WL = self._head.CalcPoseInWorld(self._plant_context.Eval(context))
            return X_WL.translation()[:2] * M_TO_MM, X_WL.rotation().matrix()[:2, 0]

        def _calc(self, context, value):
            origin, u = self._beam(context)
            j = int(_value(self.get_input_port(1).Eval(context))[0])
            d0 = self.GetDeadPaths(context)[j]
            o, ux = _value(origin), _value(u)
            count = int(_value(context.get_discrete_state_vector().CopyToVector())[0])
            rng = np.random.default_rng([self._seed, count])
            reading, valid, miss = simulate_readings(o[None], [np.degrees(np.arctan2(ux[1], ux[0]))],
                                                     self._P[j][None], [_value([d0])[0]], self._options,
                                                     self._budget, rng)
            v = self._P[j] - origin
            exact = (v[0] * u[0] + v[1] * u[1]) if self._options.cosine_error else (v[0] ** 2 + v[1] ** 2) ** 0.5
            # The exact length's derivatives, the simulated reading's value (noise and quantization are constants).
            r = reading[0] if T is float else (exact - d0) + (reading[0] - _value([exact - d0])[0])
            value.set_value(np.array([r / M_TO_MM, T(float(valid[0])), T(miss[0] / M_TO_MM)], dtype=object))

    return Impl


KinematicLaserInterferometer = KinematicLaserInterferometer_[None]


class BeamInterferometer(LeafSystem):
    """The reading machinery of the 3D interferometers (six-axis and 3D machine-tool diagrams).

    A subclass declares its input ports, then calls :meth:`DeclareReading`, and gives
    :meth:`beam`: (origin (1, 3) mm, unit u (1, 3), cat's-eye centre (1, 3) mm, cat's-eye axis
    (world), dead path mm, ``pose_noise_on``) of the sample. The reading is
    :func:`~olti_drake.model.aiming3d.read_beam` (cosine error, acceptance, λ/64, budget noise; 000
    §5, 001 Table 4), cached per Context; its noise comes from a generator seeded by (seed, sample
    count) -- the count advances every ``period_s`` -- so re-evaluating a port gives the same value.
    Outputs ``displacement`` (1, m), ``valid`` (1), ``miss`` (1, m), ``status`` (:class:`ReadStatus`).
    """

    def DeclareReading(self, seed: int, period_s: float, options: InterferometerOptions, budget) -> None:
        self._seed, self._options, self._budget = int(seed), options, budget
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._count)
        self._reading = self.DeclareCacheEntry(
            "reading", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(3)), calc=self._calc_reading),
            {self.all_sources_ticket()})
        for i, name in enumerate(("displacement", "valid", "miss")):
            self.DeclareVectorOutputPort(name, 1, lambda c, o, i=i: o.SetAtIndex(0, self._reading.Eval(c)[i]))
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make(ReadStatus()), self._calc_status)

    def beam(self, context):
        raise NotImplementedError

    def _count(self, context, discrete_state):
        discrete_state.set_value([context.get_discrete_state_vector()[0] + 1])

    def _calc_status(self, context, value):
        valid = self._reading.Eval(context)[1] > 0.5
        value.set_value(ReadStatus("0000" if valid else "8001", 1, 0))

    def _calc_reading(self, context, value):
        from olti_drake.model.aiming3d import read_beam

        origin, u, target, axis, dead_mm, pose_noise_on = self.beam(context)
        rng = np.random.default_rng([self._seed, int(context.get_discrete_state_vector()[0])])
        r = read_beam(origin, u, target, axis, dead_mm, self._options, self._budget, rng, pose_noise_on=pose_noise_on)
        value.set_value(np.array([r.reading_mm[0] / 1e3, float(r.valid[0]), r.miss_mm[0] / 1e3]))


class RowSequencer(LeafSystem):
    """One row of every output table per period: the clock of a campaign (move every ``period_s``).

    ``tables``: output port name -> (K,) or (K, n) array, one row per step;
    the row index advances every period and holds at the last row.
    """

    def __init__(self, tables: dict, period_s: float):
        super().__init__()
        set_default_name(self)
        self.period_s = period_s
        self.n_steps = len(next(iter(tables.values())))
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, period_s, self._advance)
        for name, table in tables.items():
            table = np.asarray(table, dtype=float)
            size = table.shape[1] if table.ndim == 2 else 1
            self.DeclareVectorOutputPort(name, size, lambda c, o, t=table: o.SetFromVector(
                np.atleast_1d(t[self._index(c)])))

    def _index(self, context) -> int:
        return int(context.get_discrete_state_vector()[0])

    def _advance(self, context, discrete_state):
        discrete_state.set_value([min(self._index(context) + 1, self.n_steps - 1)])

    @property
    def duration_s(self) -> float:
        """Simulated time that covers every row and its reading."""
        return self.n_steps * self.period_s


class PlanSequencer(RowSequencer):
    """Walks the measurement plan once per reflector position, one row per period.

    Outputs ``arm_command`` (2, rad), ``reflector`` (1), ``measure`` (1, 0/1)
    and ``row`` (1, the plan row within the current reflector's run).
    """

    def __init__(self, theta1_deg, theta2_deg, measure, n_reflectors: int, period_s: float):
        k = len(theta1_deg)
        super().__init__({
            "arm_command": np.radians(np.column_stack([np.tile(theta1_deg, n_reflectors),
                                                       np.tile(theta2_deg, n_reflectors)])),
            "reflector": np.repeat(np.arange(n_reflectors, dtype=float), k),
            "measure": np.tile(np.asarray(measure, dtype=float), n_reflectors),
            "row": np.tile(np.arange(k, dtype=float), n_reflectors)}, period_s)


class RecordLog:
    """An append-only sequence of records held in a Context's abstract state, cheap to copy.

    Drake copies a Python abstract state value with ``copy.deepcopy`` whenever it updates or clones
    state: a tuple of n records made every step O(n) and the campaign O(n²) (4x slower). A log is a
    prefix of a list that its copies share (records are immutable tuples): a copy is O(1), an append
    at the tip extends the shared list, and an append to an older copy (another context, or a
    discarded update) forks it, so every context keeps its own readings.
    """

    __slots__ = ("_items", "_n")

    def __init__(self, items=None, n: int = 0):
        self._items = [] if items is None else items
        self._n = n

    def appended(self, record) -> "RecordLog":
        """This log with ``record`` added (this one is left as it was)."""
        items = self._items if self._n == len(self._items) else self._items[:self._n]
        items.append(record)
        return RecordLog(items, self._n + 1)

    def __deepcopy__(self, memo) -> "RecordLog":
        return RecordLog(self._items, self._n)

    __copy__ = lambda self: RecordLog(self._items, self._n)  # noqa: E731

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, key):
        if isinstance(key, slice):
            return self._items[slice(*key.indices(self._n))]
        if not -self._n <= key < self._n:
            raise IndexError(key)
        return self._items[key % self._n]

    def __iter__(self):
        return iter(self._items[:self._n])

    def __bool__(self) -> bool:
        return self._n > 0


class ReadingRecorder(LeafSystem):
    """Keeps one record per reading *in the Context* (abstract state), never in the system.

    At ``offset_s`` in every ``period_s`` an unrestricted update asks :meth:`record`
    for the record of this instant (None: nothing to keep) and appends it to the
    context's tuple of records, so each Simulator (each Context) of one diagram
    has its own readings: two Simulators on one diagram do not double them.
    :meth:`GetReadings` returns them. ``sink(record, context)``, if given, is
    told of each record as it is taken (``olti run`` writes it to disk there).
    """

    def __init__(self, period_s: float, offset_s: float):
        super().__init__()
        set_default_name(self)
        self._records = self.DeclareAbstractState(AbstractValue.Make(RecordLog()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, offset_s, self._update)

    def record(self, context) -> Optional[tuple]:
        """The record of the reading at this instant, or None."""
        raise NotImplementedError

    def on_record(self, context, record) -> None:
        """Told of every new record (after it is computed, before it is in the state)."""

    def _update(self, context, state):
        record = self.record(context)
        if record is None:
            return
        records = context.get_abstract_state(self._records).get_value()
        state.get_mutable_abstract_state(self._records).set_value(records.appended(record))
        self.on_record(context, record)

    def GetReadings(self, root_context) -> tuple:
        """The records kept so far in ``root_context`` (the diagram's context, or this system's own)."""
        return tuple(self.GetMyContextFromRoot(root_context).get_abstract_state(self._records).get_value())


class CampaignRecorder(ReadingRecorder):
    """Takes the reading half a period after each move and keeps measured rows.

    Inputs ``joint_command`` (4), ``direction`` (4), ``displacement`` (1, m),
    ``valid`` (1), ``reflector`` (1), ``measure`` (1), ``row`` (1), and
    optionally ``status`` (a :class:`ReadStatus`). Each kept row is
    (reflector, θ1*, θ2*, dir1, dir2, displacement_mm, θ4*, valid, plan row)
    in mm/deg, kept in the Context (:meth:`GetReadings`) and handed to
    ``sink(row, status)`` if given (``olti run`` writes it to disk there, as it arrives).
    """

    COLUMNS = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "displacement_mm",
               "theta4_deg", "valid", "plan_row")

    def __init__(self, period_s: float, sink: Optional[Callable[[tuple, ReadStatus], None]] = None):
        super().__init__(period_s, 0.5 * period_s)
        self.sink = sink
        for name, size in (("joint_command", 4), ("direction", 4), ("displacement", 1), ("valid", 1),
                           ("reflector", 1), ("measure", 1), ("row", 1)):
            self.DeclareVectorInputPort(name, size)
        self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(ReadStatus()))

    def record(self, context):
        u = [self.get_input_port(i).Eval(context) for i in range(7)]
        cmd, direction, disp, valid, refl, measure, row = u
        if measure[0] < 0.5:
            return None
        ok = valid[0] > 0.5
        # A lost beam has no reading: NaN, never a plausible-looking number.
        return (int(refl[0]), np.degrees(cmd[0]), np.degrees(cmd[1]), int(direction[0]),
                int(direction[1]), disp[0] * M_TO_MM if ok else np.nan, np.degrees(cmd[3]),
                int(ok), int(row[0]))

    def on_record(self, context, record):
        if self.sink is not None:
            status = self._status.Eval(context) if self._status.HasValue(context) else ReadStatus()
            self.sink(record, status)
