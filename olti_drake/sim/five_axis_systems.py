"""The LeafSystems of the five-axis campaign diagram (:mod:`olti_drake.sim.five_axis_station` wires them): at module
level, so that they can be imported, subclassed and named in diagrams (issue 22). Units: SI in the ports (m, rad),
mm and deg in the parameters given from the plan.
"""

import numpy as np

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from olti_drake.model import aiming3d
from olti_drake.sim.systems import M_TO_MM, BeamInterferometer, ReadingRecorder, set_default_name


class FiveAxisNominal(LeafSystem):
    """The NOMINAL kinematics of the model file's MultibodyPlant: inputs ``command`` (n_axes; m, rad) and
    ``tool`` (1); outputs ``nominal_base`` / ``nominal_workpiece`` (3, m: the tool's nominal point in each
    frame, ``CalcRelativeTransform``) and ``catseye_axis_base`` / ``catseye_axis_workpiece`` (3: the cat's
    eye's axis, tool frame ``catseye_axis_tool``, in each frame)."""

    def __init__(self, machine, tool_offsets_mm, catseye_axis_tool):
        super().__init__()
        set_default_name(self)
        self._plant, self._machine = machine.plant, machine
        self._offsets = np.asarray(tool_offsets_mm, float) / M_TO_MM
        self._axis = np.asarray(catseye_axis_tool, float)
        self._joints = [machine.plant.GetJointByName(a) for a in machine.axes]
        self._command = self.DeclareVectorInputPort("command", len(machine.axes))
        self._tool = self.DeclareVectorInputPort("tool", 1)
        self._pose = self.DeclareCacheEntry("poses", ValueProducer(
            allocate=lambda: AbstractValue.Make((None, None)), calc=self._calc_poses), {self._command.ticket()})
        self._ctx = machine.plant.CreateDefaultContext()
        for k, frame in enumerate(("base", "workpiece")):
            self.DeclareVectorOutputPort(f"nominal_{frame}", 3,
                                         lambda c, o, k=k: o.SetFromVector(self._point(c, k)))
            self.DeclareVectorOutputPort(f"catseye_axis_{frame}", 3,
                                         lambda c, o, k=k: o.SetFromVector(self._pose.Eval(c)[k].rotation()
                                                                           .multiply(self._axis)))

    def _calc_poses(self, context, value):
        for joint, q in zip(self._joints, self._command.Eval(context)):
            (joint.set_translation if joint.type_name() == "prismatic" else joint.set_angle)(self._ctx, q)
        base, tool = self._plant.world_frame(), self._machine.frames[1]
        value.set_value((self._plant.CalcRelativeTransform(self._ctx, base, tool),
                         self._plant.CalcRelativeTransform(self._ctx, self._machine.frames[0], tool)))

    def _point(self, context, k):
        m = int(round(self._tool.Eval(context)[0]))
        return self._pose.Eval(context)[k].multiply(self._offsets[m])

class FiveAxisSteering(LeafSystem):
    """Open-loop pan/tilt command (001 Eq. (1) in 3D, :func:`~olti_drake.model.aiming3d.pan_tilt_commands`) of
    head ``station`` from its ESTIMATED centre and zeros (its station's frame) at the commanded tool point.
    Inputs ``nominal_base``, ``nominal_workpiece`` (3, m), ``station`` (1); output ``head_command`` (2, rad)."""

    def __init__(self, heads_est, station_frames):
        super().__init__()
        set_default_name(self)
        self._heads, self._frames = heads_est, tuple(station_frames)
        self._points = {f: self.DeclareVectorInputPort(f"nominal_{f}", 3) for f in ("base", "workpiece")}
        self._station = self.DeclareVectorInputPort("station", 1)
        self.DeclareVectorOutputPort("head_command", 2, self._calc)

    def _calc(self, context, output):
        j = int(round(self._station.Eval(context)[0]))
        if not self._frames:
            output.SetFromVector(np.zeros(2))
            return
        p = self._points[self._frames[j]].Eval(context) * M_TO_MM
        output.SetFromVector(np.radians(aiming3d.pan_tilt_commands(self._heads, [j], p[None])[0]))

class FiveAxisTruthTool(LeafSystem):
    """Commands -> the TRUE tool point by the error truth (:meth:`FiveAxisTruth.truth_positions`: location
    errors, bidirectional error motions, linear-axis errors). Inputs ``command`` (n_axes; m, rad),
    ``direction`` (n_rotary, ±1), ``tool`` (1); outputs ``tool_point_base``, ``tool_point_workpiece`` (3, m),
    each evaluated only when asked. A pure function of its inputs, memoized (every tool at once): a program
    repeated per station and tool is evaluated once per pose and frame (a truth changed after the system is
    built is not seen: build a new diagram)."""

    def __init__(self, machine, truth):
        super().__init__()
        set_default_name(self)
        self._machine, self._truth, self._memo = machine, truth, {}
        self._revolute = np.array([a not in "XYZ" for a in machine.axes])
        self._inputs = [self.DeclareVectorInputPort("command", len(machine.axes)),
                        self.DeclareVectorInputPort("direction", len(machine.rotary)),
                        self.DeclareVectorInputPort("tool", 1)]
        for frame in ("base", "workpiece"):
            self.DeclareVectorOutputPort(f"tool_point_{frame}", 3, lambda c, o, f=frame: o.SetFromVector(
                self._calc(c, f)))

    def _calc(self, context, frame):
        cmd, d, tool = (p.Eval(context) for p in self._inputs)
        key = (frame, cmd.tobytes(), d.tobytes())
        if key not in self._memo:  # every tool at once: one loop pass costs as much for n rows as for one
            n = len(self._truth.tool_offsets_mm)
            c = np.where(self._revolute, np.degrees(cmd), cmd * M_TO_MM)
            self._memo[key] = self._truth.truth_positions(np.repeat(c[None], n, 0), np.repeat(d[None], n, 0),
                                                          np.arange(n), frame) / M_TO_MM
        return self._memo[key][int(round(tool[0]))]

class FiveAxisInterferometer(BeamInterferometer):
    """The pan/tilt interferometer heads of a five-axis machine (the 3D machine's reading, :func:`read_beam`
    through :class:`~olti_drake.sim.systems._BeamReading`): head j's beam from its TRUE centre along its TRUE
    angles, in its station's frame (``station_frames[j]``), at the true tool point in that frame, cat's-eye
    axis in that frame. Inputs ``tool_point_base``, ``tool_point_workpiece`` (3, m), ``catseye_axis_base``,
    ``catseye_axis_workpiece`` (3), ``station`` (1), ``head_command`` (2, rad); outputs ``displacement``
    (1, m), ``valid``, ``miss`` (1, m), ``status``. Head centres and dead paths: numeric Parameters."""

    def __init__(self, heads_true, head_error, dead_paths_mm, station_frames, options, budget, seed, period_s):
        from pydrake.systems.framework import BasicVector

        super().__init__()
        set_default_name(self)
        self._zeros, self._err, self._frames = heads_true.zeros_deg, head_error, tuple(station_frames)
        P = np.asarray(heads_true.centres_mm, float).reshape(-1, 3)
        self._stations = self.DeclareNumericParameter(BasicVector(P.ravel().tolist() or [0.0] * 3))
        self._dead_paths = self.DeclareNumericParameter(BasicVector(list(dead_paths_mm) or [0.0]))
        self._in = {n: self.DeclareVectorInputPort(n, 3) for n in (
            "tool_point_base", "tool_point_workpiece", "catseye_axis_base", "catseye_axis_workpiece")}
        self._station = self.DeclareVectorInputPort("station", 1)
        self._head = self.DeclareVectorInputPort("head_command", 2)
        self.DeclareReading(seed, period_s, options, budget)

    def beam(self, context):
        j = int(round(self._station.Eval(context)[0]))
        frame = self._frames[j]
        head = np.degrees(self._head.Eval(context))[None]
        P = self.GetStations(context)
        origin, u = aiming3d.pan_tilt_beam(aiming3d.PanTiltHeads(P, self._zeros), [j], head, self._err)
        target = self._in[f"tool_point_{frame}"].Eval(context) * M_TO_MM
        return (origin, u, target[None], self._in[f"catseye_axis_{frame}"].Eval(context),
                self.GetDeadPaths(context)[j], "origin")

class RTestDevice(LeafSystem):
    """An R-test (3D probe) on the table: the displacement (3, m) of the actual ball centre (input
    ``tool_point`` (3, m), workpiece frame) from nest ``nest`` (input, 1) less that set-up's zero, plus normal
    noise σ from ``default_rng([seed, count])`` (the count advances every ``period_s``). Nests and zeros are
    numeric Parameters (mm)."""

    def __init__(self, nests_mm, zeros_mm, sigma_mm, seed, period_s):
        from pydrake.systems.framework import BasicVector

        super().__init__()
        set_default_name(self)
        self._sigma, self._seed = float(sigma_mm), int(seed)
        self._nests = self.DeclareNumericParameter(BasicVector(np.ravel(nests_mm).tolist() or [0.0] * 3))
        self._zeros = self.DeclareNumericParameter(BasicVector(np.ravel(zeros_mm).tolist() or [0.0] * 3))
        self._point = self.DeclareVectorInputPort("tool_point", 3)
        self._nest = self.DeclareVectorInputPort("nest", 1)
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, lambda c, s: s.set_value(
            [c.get_discrete_state_vector()[0] + 1]))
        self.DeclareVectorOutputPort("displacement", 3, self._calc)

    def _calc(self, context, output):
        n = int(round(self._nest.Eval(context)[0]))
        nest = context.get_numeric_parameter(self._nests).CopyToVector().reshape(-1, 3)[n]
        zero = context.get_numeric_parameter(self._zeros).CopyToVector().reshape(-1, 3)[n]
        count = int(context.get_discrete_state_vector()[0])
        noise = np.random.default_rng([self._seed, count]).standard_normal(3) * self._sigma
        output.SetFromVector((self._point.Eval(context) * M_TO_MM - nest - zero + noise) / M_TO_MM)

class FiveAxisRecorder(ReadingRecorder):
    """Half a period after each move: (row, displacement_mm -- NaN when lost or an R-test row --, valid,
    dx, dy, dz mm -- NaN on a distance row). Inputs ``row``, ``kind`` (1: 0 distance, 1 R-test),
    ``displacement`` (1, m), ``valid`` (1), ``rtest_displacement`` (3, m); only the row's kind is read."""

    def __init__(self, period_s):
        super().__init__(period_s, 0.5 * period_s)
        self._p = {n: self.DeclareVectorInputPort(n, s) for n, s in (
            ("row", 1), ("kind", 1), ("displacement", 1), ("valid", 1), ("rtest_displacement", 3))}

    def record(self, context):
        row = int(round(self._p["row"].Eval(context)[0]))
        if self._p["kind"].Eval(context)[0] > 0.5:
            return (row, np.nan, 1) + tuple(self._p["rtest_displacement"].Eval(context) * M_TO_MM)
        ok = self._p["valid"].Eval(context)[0] > 0.5
        disp = self._p["displacement"].Eval(context)[0] * M_TO_MM if ok else np.nan
        return (row, disp, int(ok), np.nan, np.nan, np.nan)
