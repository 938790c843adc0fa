"""Drake systems of the open-loop tracking interferometer campaigns (paper 000 §2; 001 in 3D).

Thin ``LeafSystem`` wrappers over the numpy modules (error map, steering,
interferometer), so the simulation and the identifier share one model: the
SCARA's (``ErrorMapJoint``, ``BeamSteering``, ``LaserInterferometer``,
``KinematicLaserInterferometer``, ``PlanSequencer``, ``CampaignRecorder``), the
six-axis (N-joint) robot's (``PanTiltSteering``, ``SerialLaserInterferometer``,
``SerialCampaignRecorder``) and the 3D machine tool's (``VolumetricTool``,
``PanTiltInterferometer``, ``Machine3DRecorder``). The readings' systems are
Drake templates over float and AutoDiffXd (``X_[T]``; ``X`` is ``X_[float]``)
whose identified quantities are numeric Parameters of the Context, so a
converted station (``ToAutoDiffXd()``) gives a reading's derivatives with
respect to them: the identification's Jacobian entries.

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
from pydrake.math import RigidTransform_, RotationMatrix_
from pydrake.systems.framework import (BasicVector, BasicVector_, LeafSystem, LeafSystem_, NumericParameterIndex,
                                       ValueProducer)
from pydrake.systems.scalar_conversion import TemplateSystem

from olti_drake.model.budget import Budget
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


def _scalar(value) -> float:
    """The float value of a float or AutoDiffXd scalar."""
    return value.value() if hasattr(value, "value") else float(value)


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
        tabulated truth -- a scenario's ``MapTable``, interpolated as the ErrorMap of its
        table --, a continuous truth, or None for a perfect axis); ports as
        :class:`ApproachErrorSystem`. The node values of every map axis (ErrorMap or table)
        are a numeric Parameter of the Context, [forward..., reverse...] deg (Eq. 6 order;
        default: the map's): :meth:`SetMapValues` / :meth:`GetMapValues` (an axis without
        one is refused in one line naming it). With
        ``ToAutoDiffXd()`` a reading is differentiable with respect to them; the
        interpolation weights (Eq. 9) are taken at the command's value (the map's
        slope in θ* is not carried), a continuous truth adds a constant.
        """

        def _construct(self, deviations, revolute, initial_direction=1.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._dev = [_tabulated(dev) for dev in deviations]
            self._declare_approach(revolute, initial_direction, T)
            self._maps = {i: self.DeclareNumericParameter(BasicVector_[T](dev.values.tolist()))
                          for i, dev in enumerate(self._dev) if isinstance(dev, ErrorMap)}

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._dev, other._revolute, other._initial_direction, converter=converter)

        def SetMapValues(self, context, axis: int, values_deg) -> None:
            """Set axis ``axis``'s node values (2N,) deg, [forward..., reverse...], in ``context``."""
            index = self._map_parameter(axis)
            n = context.get_numeric_parameter(index).size()
            if np.shape(values_deg) != (n,):
                raise ValueError(f"{self.get_name()}: axis {axis}: {np.size(values_deg)} map values given, its map "
                                 f"has {n} ([forward..., reverse...] deg)")
            context.get_mutable_numeric_parameter(index).SetFromVector(values_deg)

        def GetMapValues(self, context, axis: int) -> np.ndarray:
            """Axis ``axis``'s node values (2N,) deg in ``context``."""
            return context.get_numeric_parameter(self._map_parameter(axis)).CopyToVector()

        def _map_parameter(self, axis: int) -> int:
            """The Parameter index of axis ``axis``'s map; one line naming the axis when it has none."""
            if axis in self._maps:
                return self._maps[axis]
            if not (isinstance(axis, (int, np.integer)) and 0 <= axis < len(self._dev)):
                raise ValueError(f"{self.get_name()}: axis {axis!r}: the system has axes 0..{len(self._dev) - 1}")
            what = "no deviation" if self._dev[axis] is None else f"a continuous {type(self._dev[axis]).__name__}"
            raise ValueError(f"{self.get_name()}: axis {axis} has {what}, not a map or table: it has no map values "
                             f"(axes with map values: {sorted(self._maps) or 'none'})")

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


def _tabulated(deviation):
    """The :class:`ErrorMap` of a tabulated deviation (``grid_deg``, ``forward_deg``, ``reverse_deg`` and
    ``outside``: a scenario's ``MapTable``, which interpolates as this map does, 000 Eq. 7-9), so that its
    nodes are a Parameter; any other deviation as it is."""
    if isinstance(deviation, ErrorMap) or not all(hasattr(deviation, k) for k in ("grid_deg", "forward_deg",
                                                                                 "reverse_deg")):
        return deviation
    return ErrorMap(deviation.grid_deg, deviation.forward_deg, deviation.reverse_deg,
                    outside=getattr(deviation, "outside", "error"))


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


class _BeamReading:
    """The reading machinery of the 3D interferometers (six-axis and 3D machine-tool diagrams), any scalar type.

    A system declares its input ports, then calls :meth:`DeclareReading`, and gives :meth:`beam`:
    (origin (1, 3) mm, unit u (1, 3), cat's-eye centre (1, 3) mm, cat's-eye axis (world), dead path mm,
    ``pose_noise_on``) of the sample -- in the system's scalar type where they come from its Parameters
    or inputs. The reading's value is :func:`~olti_drake.model.aiming3d.read_beam` of their values (cosine
    error, acceptance, λ/64, budget noise; 000 §5, 001 Table 4), cached per Context; its noise comes from a
    generator seeded by (seed, sample count) -- the count advances every ``period_s`` -- so re-evaluating a
    port gives the same value. For T = AutoDiffXd its derivatives are those of the exact optical length
    minus the dead path (000 Eq. 5, 001 Eq. 3): (T − o)·u with the cosine error, ‖T − o‖ without; noise,
    quantization and beam loss are constants of the sample. Outputs ``displacement`` (1, m), ``valid`` (1),
    ``miss`` (1, m), ``status`` (:class:`ReadStatus`).
    """

    def DeclareReading(self, seed: int, period_s: float, options: InterferometerOptions, budget, T=float) -> None:
        self._seed, self._options, self._budget, self._T = int(seed), options, budget, T
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._count)
        dtype = float if T is float else object
        self._reading = self.DeclareCacheEntry(
            "reading", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(3, dtype=dtype)),
                                     calc=self._calc_reading), {self.all_sources_ticket()})
        for i, name in enumerate(("displacement", "valid", "miss")):
            self.DeclareVectorOutputPort(name, 1, lambda c, o, i=i: o.SetAtIndex(0, self._reading.Eval(c)[i]))
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make(ReadStatus()), self._calc_status)

    def beam(self, context):
        raise NotImplementedError

    def _count(self, context, discrete_state):
        discrete_state.set_value([context.get_discrete_state_vector()[0] + 1])

    def _calc_status(self, context, value):
        valid = _value(self._reading.Eval(context)[1:2])[0] > 0.5
        value.set_value(ReadStatus("0000" if valid else "8001", 1, 0))

    def _calc_reading(self, context, value):
        from olti_drake.model.aiming3d import read_beam

        origin, u, target, axis, dead_mm, pose_noise_on = self.beam(context)
        count = int(_value(context.get_discrete_state_vector().CopyToVector())[0])
        rng = np.random.default_rng([self._seed, count])
        T = self._T
        if T is float:
            r = read_beam(origin, u, target, axis, dead_mm, self._options, self._budget, rng,
                          pose_noise_on=pose_noise_on)
            value.set_value(np.array([r.reading_mm[0] / 1e3, float(r.valid[0]), r.miss_mm[0] / 1e3]))
            return
        r = read_beam(_value(origin), _value(u), _value(target), _value(axis), _scalar(dead_mm), self._options,
                      self._budget, rng, pose_noise_on=pose_noise_on)
        rel = np.asarray(target)[0] - np.asarray(origin)[0]
        length = rel @ np.asarray(u)[0] if self._options.cosine_error else (rel @ rel) ** 0.5
        exact = length - dead_mm
        # The exact length's derivatives, the simulated reading's value (noise and quantization are constants).
        reading = exact + (r.reading_mm[0] - _scalar(exact))
        reading = reading / 1e3 if isinstance(reading, T) else T(float(reading) / 1e3)   # (no T input: a constant)
        value.set_value(np.array([reading, T(float(r.valid[0])), T(r.miss_mm[0] / 1e3)], dtype=object))

    # -- the stations and their dead paths: numeric Parameters ``_stations``, ``_dead_paths`` of the system --------
    def SetStations(self, context, stations_mm) -> None:
        """Set the stations P_j (Nt, 3) mm in ``context``: the heads' centres (floor tracers, a machine's pan/tilt
        heads) or floor reflectors (robot-mounted)."""
        context.get_mutable_numeric_parameter(self._stations).SetFromVector(np.reshape(stations_mm, -1))

    def GetStations(self, context) -> np.ndarray:
        """The stations P_j (Nt, 3) mm used in ``context``."""
        return context.get_numeric_parameter(self._stations).CopyToVector().reshape(-1, 3)

    def SetDeadPaths(self, context, dead_paths_mm) -> None:
        """Set the counter zeros d0_j / L0_j (mm) of the stations in ``context`` (000 Eq. 5, 001 Eq. 3)."""
        context.get_mutable_numeric_parameter(self._dead_paths).SetFromVector(dead_paths_mm)

    def GetDeadPaths(self, context) -> np.ndarray:
        """The dead paths d0_j / L0_j (mm) used in ``context``."""
        return context.get_numeric_parameter(self._dead_paths).CopyToVector()


class BeamInterferometer(_BeamReading, LeafSystem):
    """A float 3D interferometer: a subclass declares its inputs, calls :meth:`DeclareReading` and gives
    :meth:`beam` (:class:`_BeamReading`)."""


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


# ------------------------------------------------------------------ six-axis (N-joint) robots, 3D
class PanTiltSteering(LeafSystem):
    """Open-loop pan/tilt command of the head in use (001 Eq. (1) in 3D): from the ESTIMATED centre
    and zero angles to the NOMINAL tool point of the commanded joints (the model file's plant,
    ``CalcPointsPositions``). Inputs ``joint_command`` (N, rad), ``reflector`` (1) and, with
    ``tool_input`` (several tool offsets (T, 3) mm, e.g. a machine tool's mountings), ``tool`` (1:
    the row's tool index); output ``head_command`` (2, rad).

    ``chain``: anything with the finalized ``plant``, ``tool_frame_index``, ``joint_names`` (chain
    order) and ``n_joints`` -- a :class:`~olti_drake.model.chain.SerialChain`, or the 3D machine's
    nominal XYZ plant; ``heads_est``: the :class:`~olti_drake.model.aiming3d.PanTiltHeads` estimates.
    Float only: the command is a decision made before the run, not a reading."""

    def __init__(self, chain, tool_offset_mm, heads_est, tool_input: bool = False):
        super().__init__()
        set_default_name(self)
        self._plant, self._heads = chain.plant, heads_est
        self._tool = chain.plant.get_frame(chain.tool_frame_index)
        self._points = np.atleast_2d(np.asarray(tool_offset_mm, float)).T / M_TO_MM  # (3, T) m
        self._starts = np.array([chain.plant.GetJointByName(n).position_start() for n in chain.joint_names])
        command = self.DeclareVectorInputPort("joint_command", chain.n_joints)
        self.DeclareVectorInputPort("reflector", 1)
        self._tool_port = self.DeclareVectorInputPort("tool", 1) if tool_input else None
        self._plant_context = self.DeclareCacheEntry(
            "plant_context", ValueProducer(allocate=lambda: AbstractValue.Make(self._plant.CreateDefaultContext()),
                                           calc=self._calc_plant_context), {command.ticket()})
        self.DeclareVectorOutputPort("head_command", 2, self._calc)

    def _calc_plant_context(self, context, value):
        q = np.zeros(self._plant.num_positions())
        q[self._starts] = self.get_input_port(0).Eval(context)
        self._plant.SetPositions(value.get_mutable_value(), q)

    def _calc(self, context, output):
        from olti_drake.model.aiming3d import pan_tilt_commands

        j = int(self.get_input_port(1).Eval(context)[0])
        m = int(round(self._tool_port.Eval(context)[0])) if self._tool_port is not None else 0
        p = self._plant.CalcPointsPositions(self._plant_context.Eval(context), self._tool, self._points[:, [m]],
                                            self._plant.world_frame())[:, 0] * M_TO_MM
        output.SetFromVector(np.radians(pan_tilt_commands(self._heads, [j], p[None])[0]))


def AddPanTiltSteering(builder, chain, tool_offset_mm, heads_est, tool_input: bool = False,
                       name: str = "pan_tilt_steering"):
    """Add a :class:`PanTiltSteering` of ``chain``'s plant aiming the ESTIMATED heads ``heads_est`` at the nominal
    tool point(s) ``tool_offset_mm`` (mm, tool frame) to ``builder``; returns it."""
    return builder.AddNamedSystem(name, PanTiltSteering(chain, tool_offset_mm, heads_est, tool_input=tool_input))


class _PosedPlant:
    """A beam system's plant Context (its cache value) and the location errors last set on its joint frames.

    The frames are re-posed only when the errors change, not at every new joint position (six poses set
    cost 7x the kinematics). Drake clones a cache value with ``copy.deepcopy``: the copy gets its own Context.
    """

    __slots__ = ("context", "located")

    def __init__(self, context, located=None):
        self.context, self.located = context, located

    def __deepcopy__(self, memo) -> "_PosedPlant":
        return _PosedPlant(self.context.Clone(), self.located)


def _checked(values, shape, what: str, where: str) -> np.ndarray:
    """``values`` as a finite float array of ``shape``; one-line ValueError naming ``where`` and ``what``."""
    a = np.asarray(values, dtype=float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: {what} must be {shape} finite values, got shape {np.shape(values)}")
    return a


@TemplateSystem.define("SerialLaserInterferometer_", T_list=(float, AutoDiffXd))
def SerialLaserInterferometer_(T):
    """SerialLaserInterferometer for scalar type T (float or AutoDiffXd): ``SerialLaserInterferometer_[T]``.

    Not symbolic: noise, quantization and beam loss are decided on values.
    """

    class Impl(_BeamReading, LeafSystem_[T]):
        """The interferometer of a six-axis (N-joint) campaign in 3D (000 §5: cosine error, acceptance, λ/64, noise).

        Input ``position`` (N, rad): the actual joint angles in chain order (e.g. :class:`ErrorMapJoint`'s
        ``position``); ``reflector`` (1): station j; floor tracers also ``head_command`` (2, rad: pan,
        tilt). Outputs ``displacement`` (1, m), ``valid`` (1), ``miss`` (1, m), ``status``
        (:class:`_BeamReading`).

        The true tool frame comes from ``chain``'s MultibodyPlant (a :class:`~olti_drake.model.chain.SerialChain`:
        the model file's plant, its joints and tool frame) in T, its joint frames moved by the location
        errors: joint i's frame on its parent X_PF becomes X_PF·Trans(δ)·Rx·Ry·Rz (the chain model's Δ_i,
        000 Eq. (3) in 3D), set in the plant's Context; the tool point p = o + R t (t the tool offset).

        Numeric Parameters of the Context (defaults: the constructor's), what the identification of a
        distance campaign estimates (:class:`~olti_drake.model.serial.DistanceMeasurement`):

        * ``chain_params`` (6N + 3): the location errors of every joint frame and the tool offset, in the
          order and units of :meth:`~olti_drake.model.chain.SerialChain.parameter_names` (``<joint>_dx_mm``
          … ``<joint>_drz_deg``, ``tool_x_mm`` …): :meth:`SetChainParameters` / :meth:`GetChainParameters`;
        * ``stations_mm`` (Nt, 3): the stations P_j (``P<j>_x_mm`` …): the true head centres (floor
          tracers) or floor reflectors (robot-mounted): :meth:`SetStations` / :meth:`GetStations`;
        * ``dead_paths_mm`` (Nt,): the counter zeros d0_j (``d0_<j>_mm``, 000 Eq. 5):
          :meth:`SetDeadPaths` / :meth:`GetDeadPaths`.

        Converted with ``ToAutoDiffXd()`` a reading is differentiable with respect to all of them and the
        position input (so, through :class:`ErrorMapJoint`, the map nodes): with the cosine error, noise,
        quantization and beam loss off it is ‖p − P_j‖ − d0_j, the identification's model (000 Eq. (10) in
        3D), and its derivatives are the identification's Jacobian.

        The beam: floor tracers (``laser_direction`` None) -- it leaves the head centre P_j along the head's
        TRUE angles (command + ``head_errors[j]`` + ``head_zeros_deg[j]``,
        :func:`~olti_drake.model.aiming3d.pan_tilt_beam`; the direction is taken at the command's value:
        no Parameter moves it) and reads the cat's eye at the tool point, axis ``catseye_axis`` in the tool
        frame. Robot-mounted (``laser_direction``: the beam's direction in the tool frame) -- it leaves the
        tool point along that direction and reads the floor reflector at P_j, axis ``catseye_axis`` in the
        world. ``options``, ``budget`` (None: no noise), ``seed``, ``period_s``: the reading
        (:class:`_BeamReading`). Units: mm and degrees in the arguments and Parameters, SI on the ports.
        """

        def _construct(self, chain, chain_params, stations_mm, dead_paths_mm, options: InterferometerOptions,
                       budget=None, seed: int = 0, period_s: float = 1.0, laser_direction=None, head_zeros_deg=None,
                       head_errors=(), catseye_axis=(0.0, 0.0, 1.0), converter=None):
            from olti_drake.model.aiming3d import _unit

            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._args = dict(chain=chain, chain_params=chain_params, stations_mm=stations_mm,
                              dead_paths_mm=dead_paths_mm, options=options, budget=budget, seed=seed,
                              period_s=period_s, laser_direction=laser_direction, head_zeros_deg=head_zeros_deg,
                              head_errors=head_errors, catseye_axis=catseye_axis)
            where = f"{self.get_name()} ({chain.path})"
            n = self._n = chain.n_joints
            params = _checked(chain_params, (6 * n + 3,), "chain_params (6 location errors per joint, tool offset)",
                              where)
            n_st = len(np.atleast_2d(np.asarray(stations_mm, float)))
            P = _checked(stations_mm, (max(n_st, 1), 3), "stations_mm (Nt, 3), Nt >= 1", where)
            dead = _checked(dead_paths_mm, (n_st,), "dead_paths_mm (one per station)", where)
            self.tracers = laser_direction is None
            self._laser = None if self.tracers else _unit(laser_direction)
            self._axis = _unit(catseye_axis)
            self._zeros = (np.zeros((n_st, 2)) if head_zeros_deg is None else
                           _checked(head_zeros_deg, (n_st, 2), "head_zeros_deg (Nt, 2)", where))
            errors = tuple(head_errors) or (None,) * n_st
            if len(errors) != n_st:
                raise ValueError(f"{where}: head_errors: {len(errors)} given for {n_st} stations")
            self._head_errors = errors
            # The plant in this scalar type; its joint frames must be offset frames to carry location errors.
            self._plant = plant = chain.plant if T is float else chain.plant.ToAutoDiffXd()
            self._tool = plant.get_frame(chain.tool_frame_index)
            self._starts = np.array([plant.GetJointByName(j).position_start() for j in chain.joint_names])
            self._frames = [plant.GetJointByName(j).frame_on_parent() for j in chain.joint_names]
            for frame in self._frames:
                if not hasattr(frame, "SetPoseInParentFrame"):
                    raise ValueError(f"robot model {chain.path}: joint frame '{frame.name()}' is not an offset "
                                     f"frame; its location errors cannot be simulated")
            default = plant.CreateDefaultContext()
            self._nominal = [frame.GetPoseInParentFrame(default) for frame in self._frames]
            self._params = self.DeclareNumericParameter(BasicVector_[T](params.tolist()))
            self._stations = self.DeclareNumericParameter(BasicVector_[T](P.ravel().tolist()))
            self._dead_paths = self.DeclareNumericParameter(BasicVector_[T](dead.tolist()))
            position = self.DeclareVectorInputPort("position", n)
            self.DeclareVectorInputPort("reflector", 1)
            if self.tracers:
                self.DeclareVectorInputPort("head_command", 2)
            self._plant_context = self.DeclareCacheEntry(
                "plant_context", ValueProducer(allocate=lambda: AbstractValue.Make(
                    _PosedPlant(self._plant.CreateDefaultContext())), calc=self._calc_plant_context),
                {position.ticket(), self.numeric_parameter_ticket(NumericParameterIndex(self._params))})
            self.DeclareReading(seed, period_s, options, budget, T)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, **other._args, converter=converter)

        # -- the Parameters ------------------------------------------------------------------------
        def SetChainParameters(self, context, chain_params) -> None:
            """Set the location errors and tool offset (6N + 3; mm, deg: ``SerialChain.parameter_names()``)."""
            context.get_mutable_numeric_parameter(self._params).SetFromVector(chain_params)

        def GetChainParameters(self, context) -> np.ndarray:
            """The location errors and tool offset (6N + 3; mm, deg) used in ``context``."""
            return context.get_numeric_parameter(self._params).CopyToVector()

        # -- the kinematics ------------------------------------------------------------------------
        def _location(self, g):
            """Δ = Trans(δ)·Rx(δrx)·Ry(δry)·Rz(δrz) of one joint frame's location errors ``g`` (6,) mm, deg, in T."""
            R = RotationMatrix_[T]
            rad = np.radians if T is float else (lambda v: v * (np.pi / 180.0))
            return RigidTransform_[T](R.MakeXRotation(rad(g[3])) @ R.MakeYRotation(rad(g[4]))
                                      @ R.MakeZRotation(rad(g[5])), g[:3] / M_TO_MM)

        def _calc_plant_context(self, context, value):
            posed = value.get_mutable_value()
            g = self.GetChainParameters(context)[:6 * self._n].reshape(self._n, 6)
            if T is not float or posed.located is None or not np.array_equal(posed.located, g):
                for frame, X0, gi in zip(self._frames, self._nominal, g):
                    frame.SetPoseInParentFrame(posed.context, X0 @ self._location(gi))
                posed.located = g.copy() if T is float else None
            nq = self._plant.num_positions()
            q = np.zeros(nq) if T is float else np.array([T(0.0)] * nq, dtype=object)
            q[self._starts] = self.get_input_port(0).Eval(context)
            self._plant.SetPositions(posed.context, q)

        def beam(self, context):
            from olti_drake.model.aiming3d import PanTiltHeads, pan_tilt_beam

            X = self._tool.CalcPoseInWorld(self._plant_context.Eval(context).context)
            R, o = X.rotation().matrix(), X.translation() * M_TO_MM
            tool_point = o + R @ self.GetChainParameters(context)[6 * self._n:]
            j = int(_value(self.get_input_port(1).Eval(context))[0])
            P = self.GetStations(context)
            dead = self.GetDeadPaths(context)[j]
            if self.tracers:
                head = np.degrees(_value(self.get_input_port(2).Eval(context)))[None]
                origin, u = pan_tilt_beam(PanTiltHeads(_value(P), self._zeros), [j], head, self._head_errors[j])
                if T is not float:
                    origin = P[j][None]   # the same point, with its derivatives
                return origin, u, tool_point[None], _value(R) @ self._axis, dead, "target"
            return tool_point[None], (R @ self._laser)[None], P[j][None], self._axis, dead, "origin"

    return Impl


SerialLaserInterferometer = SerialLaserInterferometer_[None]


def AddSerialInterferometer(builder, chain, chain_params, stations_mm, dead_paths_mm, options: InterferometerOptions,
                            name: str = "serial_laser_interferometer", **kwargs):
    """Add a :class:`SerialLaserInterferometer` on ``chain``'s plant (a :class:`~olti_drake.model.chain.SerialChain`)
    to ``builder``; returns it. ``chain_params`` (6N + 3; mm, deg), ``stations_mm`` (Nt, 3), ``dead_paths_mm``
    (Nt,) are its Parameters' defaults; ``kwargs`` the rest of its arguments (``budget``, ``seed``,
    ``period_s``, ``laser_direction`` for a robot-mounted laser, ``head_zeros_deg``, ``head_errors``,
    ``catseye_axis``). Its ``position`` input takes the actual joint angles (N, rad, chain order)."""
    return builder.AddNamedSystem(name, SerialLaserInterferometer(chain, chain_params, stations_mm, dead_paths_mm,
                                                                  options, **kwargs))


class SerialCampaignRecorder(ReadingRecorder):
    """Takes the reading half a period after each move and keeps the measured rows:
    (station, θ1*..θN* deg, dir1..dirN, displacement mm (NaN when the beam is lost), valid, plan row).
    Inputs ``joint_command`` (N), ``direction`` (N), ``displacement``, ``valid``, ``reflector``,
    ``measure``, ``row``, ``status``."""

    def __init__(self, n_joints: int, period_s: float):
        super().__init__(period_s, 0.5 * period_s)
        self._n = n_joints
        for name, size in (("joint_command", n_joints), ("direction", n_joints), ("displacement", 1),
                           ("valid", 1), ("reflector", 1), ("measure", 1), ("row", 1)):
            self.DeclareVectorInputPort(name, size)
        self.DeclareAbstractInputPort("status", AbstractValue.Make(ReadStatus()))

    def record(self, context):
        if self.GetInputPort("measure").Eval(context)[0] < 0.5:
            return None  # an approach row: nothing read (nor computed)
        cmd, direction, disp, valid, refl, _, row = (self.get_input_port(i).Eval(context) for i in range(7))
        ok = valid[0] > 0.5
        return ((int(refl[0]),) + tuple(np.degrees(cmd)) + tuple(int(d) for d in direction)
                + (disp[0] * M_TO_MM if ok else np.nan, int(ok), int(row[0])))


# ------------------------------------------------------------------ the 3D machine tool
def _as_T(values, T) -> np.ndarray:
    """A float or mixed float/AutoDiffXd array as an array of T (a float becomes a constant)."""
    if T is float:
        return np.asarray(values, dtype=float)
    return np.array([v if isinstance(v, T) else T(float(v)) for v in np.ravel(values)], dtype=object)


@TemplateSystem.define("VolumetricTool_", T_list=(float, AutoDiffXd))
def VolumetricTool_(T):
    """VolumetricTool for scalar type T (float or AutoDiffXd): ``VolumetricTool_[T]``.

    Not symbolic: the B-spline basis is evaluated at the command's value.
    """

    class Impl(LeafSystem_[T]):
        """Commanded axes -> the TRUE tool point of a 3-axis machine (the 21 ISO 230-1 error motions composed
        exactly, :func:`~olti_drake.model.volumetric3d.tool_positions`; docs/machine_3d.md).

        Inputs ``command`` (3, m), ``tool`` (1: the tool index); output ``tool_point`` (3, m), workpiece frame.
        ``config``: the :class:`~olti_drake.model.volumetric3d.MachineConfig`; ``truth``: its error motions.

        A spline truth (:class:`~olti_drake.model.volumetric3d.SplineMotions`: the identified model's
        family) is a numeric Parameter of the Context, the parameter vector of
        :class:`~olti_drake.model.volumetric3d.VolumetricModel` (``config``, the tool offsets of tools 1, 2,
        … identified when there are several): the free B-spline coefficients ``E_XX[j]`` … (mm, µrad), the
        squareness ``E_C0Y_urad`` …, ``tool<m>_x_mm`` …, as :meth:`parameter_names` names them;
        :meth:`SetVolumetricParameters` / :meth:`GetVolumetricParameters`. With ``ToAutoDiffXd()`` the
        tool point is differentiable with respect to them (the basis taken at the command's value). A
        continuous truth (``SineMotions``) has no Parameter: it adds its value as a constant.
        """

        def _construct(self, config, truth, converter=None):
            from olti_drake.model.volumetric3d import SplineMotions, VolumetricModel

            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._config, self._truth = config, truth
            self._model = self._theta = None
            self.DeclareVectorInputPort("command", 3)
            self.DeclareVectorInputPort("tool", 1)
            if isinstance(truth, SplineMotions):
                self._model = VolumetricModel(config, identify_tool_offsets=len(config.tools) > 1)
                theta = self._model.parameters_of(truth)
                self._theta = self.DeclareNumericParameter(BasicVector_[T](theta.tolist()))
                # The motions of the Parameter (their splines are built once per parameter change).
                self._motions = self.DeclareCacheEntry(
                    "motions", ValueProducer(allocate=lambda: AbstractValue.Make(truth), calc=self._calc_motions),
                    {self.numeric_parameter_ticket(NumericParameterIndex(self._theta))})
            self.DeclareVectorOutputPort("tool_point", 3, self._calc)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._config, other._truth, converter=converter)

        def parameter_names(self) -> tuple:
            """Names of the volumetric Parameter's entries (``VolumetricModel.parameter_names()``); () without."""
            return () if self._model is None else self._model.parameter_names()

        def SetVolumetricParameters(self, context, theta) -> None:
            """Set the spline truth's parameter vector (mm, µrad; :meth:`parameter_names`) in ``context``."""
            context.get_mutable_numeric_parameter(self._parameter()).SetFromVector(theta)

        def GetVolumetricParameters(self, context) -> np.ndarray:
            """The spline truth's parameter vector (mm, µrad) used in ``context``."""
            return context.get_numeric_parameter(self._parameter()).CopyToVector()

        def _parameter(self) -> int:
            if self._theta is None:
                raise ValueError(f"{self.get_name()}: the truth is a continuous {type(self._truth).__name__}, not "
                                 f"the spline model: it has no volumetric parameters")
            return self._theta

        def _calc_motions(self, context, value):
            value.set_value(self._model.motions(self.GetVolumetricParameters(context)))

        def _calc(self, context, output):
            from olti_drake.model.volumetric3d import tool_positions

            cmd = _value(self.get_input_port(0).Eval(context)) * M_TO_MM
            m = int(round(_value(self.get_input_port(1).Eval(context))[0]))
            motions = self._truth if self._theta is None else self._motions.Eval(context)
            output.SetFromVector(_as_T(tool_positions(self._config, motions, cmd[None], [m])[0] / M_TO_MM, T))

    return Impl


VolumetricTool = VolumetricTool_[None]


@TemplateSystem.define("PanTiltInterferometer_", T_list=(float, AutoDiffXd))
def PanTiltInterferometer_(T):
    """PanTiltInterferometer for scalar type T (float or AutoDiffXd): ``PanTiltInterferometer_[T]``.

    Not symbolic: noise, quantization and beam loss are decided on values.
    """

    class Impl(_BeamReading, LeafSystem_[T]):
        """The interferometer on pan/tilt heads reading a cat's eye at a given point (001 in 3D).

        Inputs ``tool_point`` (3, m: the true cat's-eye centre, e.g. :class:`VolumetricTool`'s), ``station``
        (1: head j), ``head_command`` (2, rad). The beam leaves head j's TRUE centre along its TRUE angles
        (:func:`~olti_drake.model.aiming3d.pan_tilt_beam` of ``heads_true`` with ``head_error``: command +
        error + true zeros; the direction is taken at the command's value) and reads against the counter
        zero d0_j (001 Eq. 3), cat's-eye axis ``catseye_axis`` (world), pose noise on ``pose_noise_on``
        (the head: 001's rotary axis). Outputs ``displacement`` (1, m), ``valid`` (1), ``miss`` (1, m),
        ``status`` (:class:`_BeamReading`).

        Numeric Parameters of the Context, what :class:`~olti_drake.estimation.volumetric.VolumetricIdentification`
        estimates with the motions: ``stations_mm`` (Nt, 3), the head centres ``P<j>_x_mm`` … (default
        ``heads_true.centres_mm``): :meth:`SetStations` / :meth:`GetStations`; ``dead_paths_mm`` (Nt,)
        ``L0_<j>_mm``: :meth:`SetDeadPaths` / :meth:`GetDeadPaths`. With ``ToAutoDiffXd()`` a reading is
        differentiable with respect to them and the tool point.
        """

        def _construct(self, heads_true, head_error, dead_paths_mm, catseye_axis, options, budget, seed: int,
                       period_s: float, pose_noise_on: str = "origin", converter=None):
            LeafSystem_[T].__init__(self, converter)
            set_default_name(self)
            self._args = (heads_true, head_error, dead_paths_mm, catseye_axis, options, budget, seed, period_s,
                          pose_noise_on)
            P = np.asarray(heads_true.centres_mm, float)
            dead = _checked(dead_paths_mm, (len(P),), "dead_paths_mm (one per head)", self.get_name())
            self._zeros, self._err = heads_true.zeros_deg, head_error
            self._axis, self._pose = np.asarray(catseye_axis, float), pose_noise_on
            self._stations = self.DeclareNumericParameter(BasicVector_[T](P.ravel().tolist()))
            self._dead_paths = self.DeclareNumericParameter(BasicVector_[T](dead.tolist()))
            self.DeclareVectorInputPort("tool_point", 3)
            self.DeclareVectorInputPort("station", 1)
            self.DeclareVectorInputPort("head_command", 2)
            self.DeclareReading(seed, period_s, options, budget, T)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, *other._args, converter=converter)

        def beam(self, context):
            from olti_drake.model.aiming3d import PanTiltHeads, pan_tilt_beam

            target = self.get_input_port(0).Eval(context) * M_TO_MM
            j = int(round(_value(self.get_input_port(1).Eval(context))[0]))
            head = np.degrees(_value(self.get_input_port(2).Eval(context)))[None]
            P = self.GetStations(context)
            origin, u = pan_tilt_beam(PanTiltHeads(_value(P), self._zeros), [j], head, self._err)
            if T is not float:
                origin = P[j][None]   # the same point, with its derivatives
            return origin, u, target[None], self._axis, self.GetDeadPaths(context)[j], self._pose

    return Impl


PanTiltInterferometer = PanTiltInterferometer_[None]


class Machine3DRecorder(ReadingRecorder):
    """Takes the reading half a period after each move: the row (station, target, x/y/z_cmd_mm, tool,
    displacement_mm -- NaN when the beam is lost --, valid) followed by the true tool point (mm).
    Inputs ``station``, ``target``, ``tool`` (1), ``target_command`` (3, m), ``displacement`` (1, m),
    ``valid`` (1), ``position`` (3, m)."""

    def __init__(self, period_s: float):
        super().__init__(period_s, 0.5 * period_s)
        for name, size in (("station", 1), ("target", 1), ("tool", 1), ("target_command", 3),
                           ("displacement", 1), ("valid", 1), ("position", 3)):
            self.DeclareVectorInputPort(name, size)

    def record(self, context):
        station, target, tool, cmd, disp, valid, pos = (self.get_input_port(i).Eval(context) for i in range(7))
        ok = valid[0] > 0.5
        return ((int(round(station[0])), int(round(target[0]))) + tuple(cmd * M_TO_MM)
                + (int(round(tool[0])), disp[0] * M_TO_MM if ok else np.nan, int(ok)) + tuple(pos * M_TO_MM))
