"""A live Meshcat view of a six-axis (N-joint) campaign: the arm, the stations, the beam and the error vectors in 3D.

:func:`add_serial_view` adds, next to the station of :func:`olti_drake.sim.serial_station.build_serial_diagram`:

- the arm: a view-only ``MultibodyPlant`` of the robot's model file (its visual geometry, in a SceneGraph of its
  own) posed by the station's ``true_position`` (the actual joint angles, deviations included) through
  ``MultibodyPositionToGeometryPose`` and drawn by ``MeshcatVisualizer``;
- :class:`SerialCampaignView`: the stations (floor tracer heads or floor reflectors) as spheres, the beam from the
  station in use to the tool point (red while the counter reads, grey when it is lost), and at every measured
  row the positioning error vector from the commanded tool point (the nominal model: the controller's idea) to the
  actual one (the truth), magnified ``error_scale`` times (red: the first joint approached in +, blue: in −).

The error vectors live in the Context (abstract state), so two Simulators on one diagram each have their own.
Units: mm and degrees at the API, SI at the ports and in Meshcat.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Cylinder, Rgba, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem

from olti_drake.sim.meshcat_view import (BEAM_RADIUS_M, BEAM_RGBA, FORWARD_RGBA, LOST_RGBA, REVERSE_RGBA, SegmentLog,
                                         start_meshcat)
from olti_drake.sim.systems import RecordLog, set_default_name

M_TO_MM = 1e3
PREFIX = "six_axis"
STATION_RGBA = Rgba(0.1, 0.5, 0.9, 1.0)
__all__ = ["SerialCampaignView", "add_serial_view", "start_meshcat"]


class ChainToPlantPositions(LeafSystem):
    """Input ``position`` (N chain angles, rad) -> output ``q`` (the view plant's positions: the chain's joints
    at their indices, every other joint at 0; a non-finite angle as 0)."""

    def __init__(self, n_plant: int, indices):
        super().__init__()
        set_default_name(self)
        self._n, self._idx = int(n_plant), np.asarray(indices, dtype=int)
        self.DeclareVectorInputPort("position", len(self._idx))
        self.DeclareVectorOutputPort("q", n_plant, self._calc)

    def _calc(self, context, output: BasicVector):
        q = np.zeros(self._n)
        q[self._idx] = np.nan_to_num(self.get_input_port(0).Eval(context), nan=0.0)
        output.SetFromVector(q)


class SerialCampaignView(SegmentLog, LeafSystem):
    """Stations, beam and error vectors of an N-joint campaign (module docstring).

    Inputs ``joint_command`` (N, rad), ``true_position`` (N, rad: actual angles), ``direction`` (N, ±1),
    ``reflector`` (1: the station in use), ``valid`` (1), ``measure`` (1). ``commanded(θ* deg) -> (3,) mm`` and
    ``actual(θ deg) -> (3,) mm`` give the tool point by the nominal model and by the truth.
    """

    def __init__(self, meshcat, stations_mm, commanded, actual, period_s: float, offset_s: float,
                 scale: float = 500.0, prefix: str = PREFIX):
        super().__init__()
        set_default_name(self)
        self._meshcat, self._commanded, self._actual, self._scale = meshcat, commanded, actual, float(scale)
        self._stations = np.asarray(stations_mm, dtype=float) / M_TO_MM
        self.beam_path, self.path = f"{prefix}/beam", f"{prefix}/errors"
        for name in ("joint_command", "true_position", "direction"):
            self.DeclareVectorInputPort(name, commanded.n_joints)
        for name in ("reflector", "valid", "measure"):
            self.DeclareVectorInputPort(name, 1)
        self._state = self.DeclareAbstractState(AbstractValue.Make({"forward": RecordLog(), "reverse": RecordLog()}))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, offset_s, self._add)
        self.DeclarePeriodicPublishEvent(period_s, (offset_s + 0.25 * period_s) % period_s, self._draw)
        self.DeclareForcedPublishEvent(self._draw)
        for j, p in enumerate(self._stations):
            meshcat.SetObject(f"{prefix}/stations/{j}", Sphere(0.03), STATION_RGBA)
            meshcat.SetTransform(f"{prefix}/stations/{j}", RigidTransform(p))

    def _points(self, context):
        cmd = np.degrees(self.GetInputPort("joint_command").Eval(context))
        act = np.degrees(self.GetInputPort("true_position").Eval(context))
        return self._commanded(cmd) / M_TO_MM, self._actual(act) / M_TO_MM

    def _add(self, context, state):
        if self.GetInputPort("measure").Eval(context)[0] < 0.5:
            return
        c, a = self._points(context)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(a))):
            return
        kind = "forward" if self.GetInputPort("direction").Eval(context)[0] > 0 else "reverse"
        segments = dict(self._segments(context))
        segments[kind] = segments[kind].appended((tuple(c), tuple(c + self._scale * (a - c))))
        state.get_mutable_abstract_state(self._state).set_value(segments)

    def _draw(self, context):
        _, tool = self._points(context)
        j = int(self.GetInputPort("reflector").Eval(context)[0])
        valid = self.GetInputPort("valid").Eval(context)[0] > 0.5
        if 0 <= j < len(self._stations) and np.all(np.isfinite(tool)):
            a, b = self._stations[j], tool
            length = float(np.linalg.norm(b - a))
            if length > 1e-9:
                R = RotationMatrix.MakeFromOneVector((b - a) / length, 2)  # Drake cylinders run along z
                self._meshcat.SetObject(self.beam_path, Cylinder(BEAM_RADIUS_M, length),
                                        BEAM_RGBA if valid else LOST_RGBA)
                self._meshcat.SetTransform(self.beam_path, RigidTransform(R, (a + b) / 2))
        self._draw_segments(context, {"forward": FORWARD_RGBA, "reverse": REVERSE_RGBA})


class _ToolPoint:
    """θ (deg) -> tool point (mm) of a chain with fixed parameters; ``n_joints`` for the view's port sizes."""

    def __init__(self, chain, params):
        self.chain, self.params, self.n_joints = chain, np.asarray(params, dtype=float), chain.n_joints

    def __call__(self, theta_deg):
        return self.chain.positions(np.asarray(theta_deg, dtype=float)[None], self.params)[0]


def add_serial_view(builder, meshcat, setup, station, sequencer, error_scale: float = 500.0):
    """Add the Meshcat view of a six-axis campaign (module docstring) to ``builder``; returns its systems."""
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, SceneGraph
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.rendering import MultibodyPositionToGeometryPose

    from olti_drake.model.chain import _weld_root

    s, chain = setup.scenario, setup.chain
    scene_graph = builder.AddNamedSystem("view_scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    try:
        instances = Parser(plant).AddModels(chain.path)
    except Exception as e:  # noqa: BLE001 (Drake's parser raises RuntimeError with its own text)
        first = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
        raise ValueError(f"--meshcat: the robot model {chain.path} cannot be shown (its geometry: {first}); "
                         f"simulate without --meshcat") from None
    _weld_root(plant, instances, chain.path)
    plant.Finalize()
    indices = [plant.GetJointByName(name).position_start() for name in chain.joint_names]
    to_q = builder.AddNamedSystem("view_positions", ChainToPlantPositions(plant.num_positions(), indices))
    to_pose = builder.AddNamedSystem("view_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(station.GetOutputPort("true_position"), to_q.get_input_port())
    builder.Connect(to_q.get_output_port(), to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    params = MeshcatVisualizerParams()
    params.publish_period = s.period_s / 2
    visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph.get_query_output_port(), meshcat, params)
    nominal = _ToolPoint(chain, chain.nominal_parameters(setup.tool_offset_mm))
    actual = _ToolPoint(chain, setup.truth.chain_params)
    view = builder.AddNamedSystem("campaign_view", SerialCampaignView(
        meshcat, setup.stations_mm, nominal, actual, s.period_s, 0.5 * s.period_s, error_scale))
    for port in ("joint_command", "reflector", "measure"):
        builder.Connect(sequencer.GetOutputPort(port), view.GetInputPort(port))
    for port in ("true_position", "direction", "valid"):
        builder.Connect(station.GetOutputPort(port), view.GetInputPort(port))
    reach = float(np.linalg.norm(setup.stations_mm, axis=1).max()) / M_TO_MM
    meshcat.SetCameraPose(np.array([-1.2, -1.6, 1.4]) * reach, np.zeros(3))
    return {"visualizer": visualizer, "campaign_view": view, "view_plant": plant}
