"""A live Meshcat view of a campaign: the arm, the laser beam, the reflectors and the error vectors.

``campaign_view(meshcat)`` returns an ``extend`` hook for
:func:`olti_drake.sim.campaign.build_campaign_diagram` / ``run_campaign`` that adds,
next to the station:

- the arm and the reflector spheres: the SceneGraph illustration geometry of
  the plant (``plant.py``) through a ``MeshcatVisualizer`` -- the simulated
  station's own SceneGraph (its ``query_object`` port), or, for an emulated or
  hardware station, a view-only kinematic plant posed by the station's
  ``position`` port (the encoder angles);
- :class:`BeamView`: the beam as a thin cylinder from the laser head to the
  reflector in use (red while the counter reads, grey when the beam is lost),
  and a translucent halo on that reflector;
- :class:`ErrorVectors`: at every measured row, a segment from the commanded
  position (nominal link lengths, the controller's idea) to the actual one
  (the plant's flange), magnified ``error_scale`` times like 000 Fig. 11
  (red: J1 approached in +, blue: in -); optionally a second set to a
  model's predicted position.

Without a view nothing of this is built, so a campaign without Meshcat costs
nothing. Scripts::

    meshcat = start_meshcat()
    print(meshcat.web_url())
    run_campaign(setup, extend=campaign_view(meshcat), realtime_rate=20)

Meshcat serves its page and JavaScript from the Drake installation itself
(no network needed).
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Cylinder, QueryObject, Rgba, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from olti_drake.model.scara import forward_kinematics
from olti_drake.sim.systems import RecordLog, set_default_name

M_TO_MM = 1e3
#: Meshcat paths (under /drake) of the view's own objects; the plant is under /drake/visualizer.
PREFIX = "campaign"
BEAM_RADIUS_M = 0.002
BEAM_RGBA, LOST_RGBA = Rgba(0.95, 0.1, 0.1, 1.0), Rgba(0.5, 0.5, 0.5, 0.6)
HALO_RGBA = Rgba(1.0, 0.85, 0.1, 0.35)
FORWARD_RGBA, REVERSE_RGBA, PREDICTED_RGBA = Rgba(0.9, 0.1, 0.1, 1), Rgba(0.1, 0.2, 0.9, 1), Rgba(0.1, 0.6, 0.1, 1)
#: Error vectors per Meshcat object: a new row re-sends only its chunk.
CHUNK = 64


def start_meshcat(port: Optional[int] = None):
    """A Meshcat server on localhost (``port`` None: the first free one from 7000)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    params = MeshcatParams()
    params.host = "localhost"
    if port is not None:
        params.port = int(port)
    return Meshcat(params)


class FinitePosition(LeafSystem):
    """Input ``position`` (n) -> output ``position`` (n) with unknown (NaN) entries as 0.

    A hardware station knows no encoder angle before its first update; the view's plant needs numbers.
    """

    def __init__(self, n: int = 4):
        super().__init__()
        set_default_name(self)
        self.DeclareVectorInputPort("position", n)
        self.DeclareVectorOutputPort("position", n, lambda c, o: o.SetFromVector(
            np.nan_to_num(self.get_input_port(0).Eval(c), nan=0.0)))


class BeamView(LeafSystem):
    """The laser beam from the laser head to the reflector in use, drawn every ``publish_period_s``.

    Inputs ``geometry_query`` (QueryObject: flange and reflector poses),
    ``reflector`` (1) and ``valid`` (1). No outputs: it publishes to Meshcat.
    """

    def __init__(self, meshcat, flange_frame_id, X_FL: RigidTransform, reflector_frame_ids, publish_period_s: float,
                 prefix: str = PREFIX, radius_m: float = BEAM_RADIUS_M):
        super().__init__()
        set_default_name(self)
        self._meshcat, self._frame, self._X_FL = meshcat, flange_frame_id, X_FL
        self._reflectors = list(reflector_frame_ids)
        self._radius = radius_m
        self.beam_path, self.halo_path = f"{prefix}/beam", f"{prefix}/reflector_in_use"
        self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.DeclareVectorInputPort("reflector", 1)
        self.DeclareVectorInputPort("valid", 1)
        self.DeclarePeriodicPublishEvent(publish_period_s, 0.0, self._draw)
        self.DeclareForcedPublishEvent(self._draw)
        meshcat.SetObject(self.halo_path, Sphere(0.03), HALO_RGBA)

    def _draw(self, context):
        query = self.get_input_port(0).Eval(context)
        j = int(self.get_input_port(1).Eval(context)[0])
        valid = self.get_input_port(2).Eval(context)[0] > 0.5
        a = (query.GetPoseInWorld(self._frame) @ self._X_FL).translation()
        b = query.GetPoseInWorld(self._reflectors[j]).translation()
        length = float(np.linalg.norm(b - a))
        if not (np.isfinite(length) and length > 1e-9):
            return
        z = (b - a) / length  # Drake cylinders run along their frame's z
        R = RotationMatrix.MakeFromOneVector(z, 2)
        self._meshcat.SetObject(self.beam_path, Cylinder(self._radius, length), BEAM_RGBA if valid else LOST_RGBA)
        self._meshcat.SetTransform(self.beam_path, RigidTransform(R, (a + b) / 2))
        self._meshcat.SetTransform(self.halo_path, RigidTransform(b))


class SegmentLog:
    """Error-vector segments kept in a LeafSystem's Context (abstract state ``self._state``: {kind: RecordLog of
    (start, end) in m}) and drawn chunk by chunk (a new row re-sends only its chunk); the views' shared part."""

    def _segments(self, context) -> dict:
        return context.get_abstract_state(self._state).get_value()

    def GetSegments(self, root_context, kind: str) -> np.ndarray:
        """(n, 2, 3) segments (start, end; m) of ``kind`` kept in ``root_context``."""
        return np.array(list(self._segments(self.GetMyContextFromRoot(root_context))[kind])).reshape(-1, 2, 3)

    def Count(self, root_context) -> int:
        """Error vectors (forward + reverse) kept in ``root_context``: one per measured row."""
        segments = self._segments(self.GetMyContextFromRoot(root_context))
        return len(segments["forward"]) + len(segments["reverse"])

    def _draw_segments(self, context, rgba: dict) -> None:
        for kind, segments in self._segments(context).items():
            if not segments:
                continue
            first = (len(segments) - 1) // CHUNK * CHUNK
            chunk = np.array(segments[first:], dtype=float)
            self._meshcat.SetLineSegments(f"{self.path}/{kind}/{first // CHUNK:03d}", chunk[:, 0].T.copy(),
                                          chunk[:, 1].T.copy(), 2.0, rgba[kind])


class ErrorVectors(SegmentLog, LeafSystem):
    """Positioning error vectors of the measured rows, magnified (000 Fig. 11 style).

    Inputs ``joint_command`` (4, rad/m: the commanded angles), ``direction``
    (4, ±1), ``measure`` (1) and ``geometry_query`` (the flange's actual pose).
    At ``offset_s`` in every ``period_s`` (the reading instant), a measured row
    adds the segment commanded -> commanded + ``scale`` (actual - commanded),
    at the flange height, red for J1 approached in +, blue in -. ``predict``
    (optional): ``(theta1_deg, theta2_deg, dir1, dir2) -> (x_mm, y_mm)`` adds
    the model's predicted error in green.

    The segments live in the Context (abstract state, appended by an unrestricted
    update), so two Simulators on one diagram each have their own:
    :meth:`GetSegments`, :meth:`Count`. A publish a quarter period later draws
    the newest chunk of each kind (drawing is idempotent: Meshcat shows the
    Context last drawn).
    """

    KINDS = ("forward", "reverse", "predicted")

    def __init__(self, meshcat, L1_mm: float, L2_mm: float, flange_frame_id, period_s: float, offset_s: float,
                 scale: float = 500.0, predict: Optional[Callable] = None, prefix: str = PREFIX):
        super().__init__()
        set_default_name(self)
        self._meshcat, self._L, self._frame = meshcat, (L1_mm, L2_mm), flange_frame_id
        self._scale, self._predict = float(scale), predict
        self.path = f"{prefix}/errors"
        self.DeclareVectorInputPort("joint_command", 4)
        self.DeclareVectorInputPort("direction", 4)
        self.DeclareVectorInputPort("measure", 1)
        self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self._state = self.DeclareAbstractState(AbstractValue.Make({k: RecordLog() for k in self.KINDS}))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, offset_s, self._add)
        self.DeclarePeriodicPublishEvent(period_s, (offset_s + 0.25 * period_s) % period_s, self._draw)

    def _add(self, context, state):
        if self.get_input_port(2).Eval(context)[0] < 0.5:
            return
        t1, t2 = np.degrees(self.get_input_port(0).Eval(context)[:2])
        d = self.get_input_port(1).Eval(context)
        actual = self.get_input_port(3).Eval(context).GetPoseInWorld(self._frame).translation()
        if not np.all(np.isfinite(actual)):
            return
        command = np.append(forward_kinematics([t1], [t2], *self._L)[0][0] / M_TO_MM, actual[2])
        segments = dict(self._segments(context))
        self._append(segments, "forward" if d[0] > 0 else "reverse", command, actual)
        if self._predict is not None:
            x, y = self._predict(t1, t2, d[0], d[1])
            self._append(segments, "predicted", command, np.array([x / M_TO_MM, y / M_TO_MM, actual[2]]))
        state.get_mutable_abstract_state(self._state).set_value(segments)

    def _append(self, segments: dict, kind: str, command, target):
        end = command + self._scale * (np.asarray(target, dtype=float) - command)
        end[2] = command[2]
        segments[kind] = segments[kind].appended((tuple(command), tuple(end)))

    def _draw(self, context):
        self._draw_segments(context, {"forward": FORWARD_RGBA, "reverse": REVERSE_RGBA, "predicted": PREDICTED_RGBA})


def add_campaign_view(builder, meshcat, setup, station, sequencer, steering, error_scale: float = 500.0,
                      predict: Optional[Callable] = None, publish_period_s: Optional[float] = None):
    """Add the Meshcat view of a campaign to ``builder`` (see the module doc); returns its systems as a dict."""
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams

    s, r = setup.scenario, setup.scenario.robot
    period = s.period_s
    publish = publish_period_s or period / 2
    plant = getattr(station, "plant", None)
    if station.HasOutputPort("query_object") and plant is not None:
        query = station.GetOutputPort("query_object")
    else:  # emulated or hardware: a view-only plant posed by the encoder angles
        from olti_drake.sim.plant import AddScaraPlant
        plant = AddScaraPlant(builder, r.L1_mm, r.L2_mm, setup.reflectors_mm, r.theta40_deg,
                                tuple(r.beam_offset_mm), name="view_plant")
        finite = builder.AddNamedSystem("view_position", FinitePosition())
        builder.Connect(station.GetOutputPort("measured_position"), finite.get_input_port())
        builder.Connect(finite.get_output_port(), plant.position_input)
        query = plant.query_output
    params = MeshcatVisualizerParams()
    params.publish_period = publish
    visualizer = MeshcatVisualizer.AddToBuilder(builder, query, meshcat, params)
    beam = builder.AddNamedSystem("beam_view", BeamView(
        meshcat, plant.flange_frame_id, plant.laser_head_in_flange, plant.reflector_frame_ids, publish))
    builder.Connect(query, beam.GetInputPort("geometry_query"))
    builder.Connect(sequencer.GetOutputPort("reflector"), beam.GetInputPort("reflector"))
    builder.Connect(station.GetOutputPort("valid"), beam.GetInputPort("valid"))
    errors = builder.AddNamedSystem("error_vectors", ErrorVectors(
        meshcat, r.nominal_L1_mm, r.nominal_L2_mm, plant.flange_frame_id, period, 0.5 * period,
        error_scale, predict))
    builder.Connect(steering.GetOutputPort("joint_command"), errors.GetInputPort("joint_command"))
    builder.Connect(station.GetOutputPort("direction"), errors.GetInputPort("direction"))
    builder.Connect(sequencer.GetOutputPort("measure"), errors.GetInputPort("measure"))
    builder.Connect(query, errors.GetInputPort("geometry_query"))
    _set_camera(meshcat, setup)
    return {"visualizer": visualizer, "beam_view": beam, "error_vectors": errors, "plant": plant}


def _set_camera(meshcat, setup) -> None:
    """Look down at the workspace and the reflectors from above and in front."""
    P = np.asarray(setup.reflectors_mm, dtype=float) / M_TO_MM
    r = setup.scenario.robot
    reach = (r.L1_mm + r.L2_mm) / M_TO_MM
    centre = np.array([P[:, 0].max() / 2, P[:, 1].mean(), 0.2])
    meshcat.SetCameraPose(centre + np.array([-1.2 * reach, -1.8 * reach, 2.2 * reach]), centre)


def campaign_view(meshcat, error_scale: float = 500.0, predict: Optional[Callable] = None,
                  publish_period_s: Optional[float] = None, systems: Optional[dict] = None):
    """An ``extend`` hook for ``build_campaign_diagram``/``run_campaign`` adding the Meshcat view.

    ``systems`` (a dict, optional) receives the added systems (``error_vectors`` …) for inspection.
    """
    def extend(builder, setup, station, sequencer, steering, recorder=None):
        added = add_campaign_view(builder, meshcat, setup, station, sequencer, steering, error_scale, predict,
                                  publish_period_s)
        if systems is not None:
            systems.update(added)

    return extend
