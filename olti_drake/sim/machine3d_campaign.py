"""The 3D machine-tool campaign on any station (``olti run``): the diagram of
:func:`~olti_drake.sim.machine3d_station.build_machine3d_diagram` with the station chosen by a factory
and an ``extend`` hook, as :func:`~olti_drake.sim.campaign.build_campaign_diagram` is for the SCARA.

    RowSequencer --target_command (3, m), station, tool--> PanTiltSteering --head_command (2, rad)--+
          |                                                                                      v
          +--target_command, station, tool-------------------------------------------> station
                                                    (simulated, emulated or hardware: displacement, valid,
                                                     status, ...) --> Machine3DRunRecorder (sink: the run log)

The station comes from ``station_factory(builder, setup)``: by default the simulated 3D station
(:func:`~olti_drake.sim.machine3d_station.AddMachine3DStation`); ``olti run`` passes
:func:`olti_drake.hardware.station.AddStation`, which reads ``setup.scenario.station``: the 3D machine
emulator or the real machine controller and pan/tilt heads behind the hardware station (their ports
have the simulated station's names: inputs ``target_command`` (3, m), ``station``, ``head_command``;
outputs ``displacement``, ``valid``, ``miss``, ``status``; the simulated one also takes ``tool`` and
gives ``true_position``). The steering is open loop either way: from the commands, the tools' nominal
offsets and the heads' ESTIMATED centres and zeros (001 Eq. 1 in 3D).

Units: mm and degrees in the API; SI on the Drake ports.
"""

import functools
import hashlib
from dataclasses import dataclass

import numpy as np

M_TO_MM = 1e3


@dataclass
class Machine3DCampaignSetup:
    """A 3D machine campaign as ``olti run`` takes it: ``scenario`` the scenario file
    (:class:`~olti_drake.sim.machine3d_station.Machine3DScenarioFile`: its ``station``, ``period_s``,
    ``seed``), ``machine`` the diagram's :class:`~olti_drake.sim.machine3d_station.Machine3DSetup`
    (the planned run shared with the numpy twin, the budget)."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine3d"

    scenario: object
    machine: object

    @property
    def run(self):
        return self.machine.run

    @property
    def heads_true(self):
        return self.machine.run.heads_true

    @property
    def stations_mm(self) -> np.ndarray:
        """The true head centres (N_j, 3) mm (one head line, one port each)."""
        return self.machine.run.heads_true.centres_mm

    @property
    def n_steps(self) -> int:
        return len(self.machine.run.sequence["station"])

    def commands_mm(self) -> np.ndarray:
        """The machine command (K, 3) mm of every sequencer row."""
        return self.run.commands_mm[self.run.sequence["target"]]

    def directions(self) -> np.ndarray:
        """The approach direction (K, 3) of every row's axes (formats.md rule over the whole sequence)."""
        s = self.run.sequence
        return np.column_stack([s["dir_x"], s["dir_y"], s["dir_z"]]).astype(float)

    def head_commands_deg(self) -> np.ndarray:
        """The open-loop pan/tilt command (K, 2) deg of every row (what the steering sends)."""
        from olti_drake.model.aiming3d import pan_tilt_commands

        r = self.run
        i, j = r.sequence["target"], r.sequence["station"]
        return pan_tilt_commands(r.heads_est, j, r.nominal_mm[i])

    def fingerprint(self) -> str:
        """SHA-256 of what a resumed session must repeat exactly: the rows (head, target, tool, command,
        the heads' aim from the estimates)."""
        r = self.run
        i, j = r.sequence["target"], r.sequence["station"]
        table = np.column_stack([j, i, r.tool[i], np.round(self.commands_mm(), 9),
                                 np.round(self.head_commands_deg(), 9)])
        return hashlib.sha256(np.ascontiguousarray(table, dtype=float).tobytes()).hexdigest()


def prepare_machine3d_campaign(doc, where: str = "scenario") -> Machine3DCampaignSetup:
    """The campaign of a validated :class:`~olti_drake.sim.machine3d_station.Machine3DScenarioFile`."""
    from olti_drake.sim.machine3d_station import prepare_machine3d

    return Machine3DCampaignSetup(doc, prepare_machine3d(doc.scenario(where), doc.load_budget(), doc.period_s))


@functools.lru_cache(maxsize=None)
def _recorder_class():
    """:class:`Machine3DRunRecorder`: the 3D recorder with the station's ``status`` as an input (pydrake is
    imported when a diagram is built, not at import)."""
    from pydrake.common.value import AbstractValue

    from olti_drake.sim.systems import Machine3DRecorder, ReadStatus

    class Machine3DRunRecorder(Machine3DRecorder):
        """The 3D machine recorder (one row per reading: station, target, x/y/z_cmd_mm, tool,
        displacement_mm -- NaN when the beam is lost --, valid, then the true tool point, mm) with the
        input ``status`` (a :class:`~olti_drake.sim.systems.ReadStatus`); ``sink(record, status)``
        is told of every row as it is taken (the run log writes it to disk there)."""

        def __init__(self, period_s: float, sink=None):
            super().__init__(period_s)
            self.sink = sink
            self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(ReadStatus()))

        def on_record(self, context, record):
            if self.sink is not None:
                status = self._status.Eval(context) if self._status.HasValue(context) else ReadStatus()
                self.sink(record, status)

    return Machine3DRunRecorder


def build_machine3d_campaign_diagram(setup: Machine3DCampaignSetup, station_factory=None, extend=None, sink=None):
    """The 3D campaign as a Diagram on the station ``station_factory(builder, setup)`` adds (default: the
    simulated one); returns (diagram, recorder, sequencer); ``diagram.station`` is the station.

    ``extend(builder, setup=, station=, sequencer=, steering=, recorder=)`` adds more systems (a logger, a
    view) before the diagram is built, as the SCARA's; ``sink(record, status)`` gets every reading."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from olti_drake.sim.machine3d_station import AddMachine3DStation, make_xyz_machine
    from olti_drake.sim.systems import AddPanTiltSteering, RowSequencer

    m = setup.machine
    run, period = m.run, m.period_s
    i, j = run.sequence["target"], run.sequence["station"]
    builder = DiagramBuilder()
    station = (station_factory or (lambda b, s: AddMachine3DStation(b, s.machine)))(builder, setup)
    xyz = make_xyz_machine()
    seq = builder.AddNamedSystem("machine_sequencer", RowSequencer({
        "target_command": run.commands_mm[i] / M_TO_MM, "station": j.astype(float), "target": i.astype(float),
        "tool": run.tool[i].astype(float)}, period))
    steer = AddPanTiltSteering(builder, xyz, run.config.tools, run.heads_est, tool_input=True)
    rec = builder.AddNamedSystem("machine_recorder", _recorder_class()(period, sink))
    builder.Connect(seq.GetOutputPort("target_command"), steer.GetInputPort("joint_command"))
    builder.Connect(seq.GetOutputPort("station"), steer.GetInputPort("reflector"))
    builder.Connect(seq.GetOutputPort("tool"), steer.GetInputPort("tool"))
    builder.Connect(steer.GetOutputPort("head_command"), station.GetInputPort("head_command"))
    for port in ("target_command", "station", "tool"):
        if station.HasInputPort(port):      # a device station has no tool input: the aim picks the cat's eye
            builder.Connect(seq.GetOutputPort(port), station.GetInputPort(port))
    for port in ("target_command", "station", "tool", "target"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("displacement", "valid", "status"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    if station.HasOutputPort("true_position"):
        builder.Connect(station.GetOutputPort("true_position"), rec.GetInputPort("position"))
    else:                                   # real devices: the true tool point is unknown
        unknown = builder.AddNamedSystem("true_position_unknown", ConstantVectorSource(np.full(3, np.nan)))
        builder.Connect(unknown.get_output_port(), rec.GetInputPort("position"))
    if extend is not None:
        extend(builder, setup=setup, station=station, sequencer=seq, steering=steer, recorder=rec)
    diagram = builder.Build()
    diagram.station, diagram.xyz = station, xyz  # keep the plant the steering reads alive
    return diagram, rec, seq


def machine3d_truth_result(setup: Machine3DCampaignSetup, valid) -> dict:
    """The simulated truth (multilateration result layout) of a campaign with these ``valid`` flags."""
    from olti_drake.model.machine import machine3d_truth

    return machine3d_truth(setup.machine.scenario, setup.run, int(np.sum(np.asarray(valid) > 0)))

