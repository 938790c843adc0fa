"""The five-axis distance campaign on any station (``olti run``): the diagram of
:func:`~olti_drake.sim.five_axis_station.build_five_axis_diagram` with the station chosen by a factory, the run
recorder telling a sink of every reading, and an ``extend`` hook, as :mod:`olti_drake.sim.machine3d_campaign` is for
the 3D machine.

    RowSequencer --command (n_axes; m, rad), tool--> FiveAxisNominal --nominal point--> FiveAxisSteering
          |                                                             --head_command (2, rad)--+
          +--command, station (direction, tool, nest: the simulated station only)------------> station
                    (simulated, emulated or hardware: displacement, valid, status) --> FiveAxisRunRecorder (sink)

The station comes from ``station_factory(builder, setup)``: by default the simulated one
(:func:`~olti_drake.sim.five_axis_station.AddFiveAxisStation`); ``olti run`` passes
:func:`olti_drake.hardware.station.AddStation`, which reads ``setup.scenario.station``: the five-axis emulator
(:mod:`olti_drake.hardware.machine5_emulator`) or the real controller and pan/tilt heads behind the hardware
station (inputs ``command``, ``station``, ``head_command``). The steering is open loop either way: from the
commands, the tools' nominal offsets and the heads' ESTIMATED centres and zeros (001 Eq. (1) with the rotary axes).

Only distance campaigns run: the line protocol carries one displacement per READ, not the R-test's three
(docs/protocol.md), so a scenario with ``rtest.nests_mm`` is refused here (``olti simulate`` simulates it).

Units: mm and degrees in the API and the log; SI on the Drake ports.
"""

import functools
import hashlib
from dataclasses import dataclass

import numpy as np

from olti_drake.errors import InputError


@dataclass
class FiveAxisCampaignSetup:
    """A five-axis campaign as ``olti run`` takes it: ``scenario`` the
    :class:`~olti_drake.sim.five_axis_station.FiveAxisScenarioFile` (its ``station``, ``period_s``, ``seed``),
    ``run`` its planned :class:`~olti_drake.sim.five_axis_station.FiveAxisRun` (one row = one reading)."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine5"

    scenario: object
    run: object

    @property
    def heads_true(self):
        return self.run.heads_true

    @property
    def stations_mm(self) -> np.ndarray:
        """The true head centres (N_j, 3) mm, each in its station's frame (one head line, one port each)."""
        return self.run.heads_true.centres_mm

    @property
    def n_steps(self) -> int:
        return len(self.run.plan)

    def fingerprint(self) -> str:
        """SHA-256 of what a resumed session must repeat exactly: the rows (commands, directions, tool,
        station) and the heads' estimates the steering aims from."""
        p, h = self.run.plan, self.run.heads_est
        table = np.column_stack([np.round(p.commands, 9), p.directions, p.tool, p.station])
        aim = np.concatenate([np.ravel(h.centres_mm), np.ravel(h.zeros_deg)])
        return hashlib.sha256(np.ascontiguousarray(table, dtype=float).tobytes()
                              + np.round(aim, 9).tobytes()).hexdigest()

    def log_record(self, row: int, displacement_mm: float, valid: int) -> tuple:
        """The run log's row (:func:`~olti_drake.hardware.runlog.machine5_columns` before the run-log columns,
        then ``plan_row``) of plan row ``row``."""
        p = self.run.plan
        j = int(p.station[row])
        return (tuple(p.commands[row]) + tuple(int(d) for d in p.directions[row])
                + (int(p.tool[row]), j, p.station_frames[j], displacement_mm, int(valid), row))


def prepare_five_axis_campaign(doc, where: str = "") -> FiveAxisCampaignSetup:
    """The campaign of a validated five-axis scenario file; R-test nests are refused (one line naming ``where``)."""
    from olti_drake.sim.five_axis_station import prepare_five_axis

    where = where or (f"scenario {doc.source_file}" if getattr(doc, "source_file", "") else "scenario")
    if doc.rtest.nests_mm:
        raise InputError(f"{where}: olti run takes five-axis distance campaigns only: rtest.nests_mm gives "
                         f"{len(doc.rtest.nests_mm)} R-test nests, but the line protocol carries one displacement per "
                         f"READ, not the R-test's three (docs/protocol.md); set rtest: {{nests_mm: []}} or simulate "
                         f"them with olti simulate")
    return FiveAxisCampaignSetup(doc, prepare_five_axis(doc, where))


@functools.lru_cache(maxsize=None)
def _recorder_class():
    """:class:`FiveAxisRunRecorder` (pydrake imported when a diagram is built, not at import)."""
    from pydrake.common.value import AbstractValue

    from olti_drake.sim.five_axis_systems import FiveAxisRecorder
    from olti_drake.sim.systems import ReadStatus

    class FiveAxisRunRecorder(FiveAxisRecorder):
        """The five-axis recorder with the input ``status`` (a :class:`~olti_drake.sim.systems.ReadStatus`);
        ``sink(log_record, status)`` is told of every distance reading as it is taken (the run log writes it)."""

        def __init__(self, setup, sink=None):
            super().__init__(setup.scenario.period_s)
            self.setup, self.sink = setup, sink
            self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(ReadStatus()))

        def on_record(self, context, record):
            if self.sink is not None:
                status = self._status.Eval(context) if self._status.HasValue(context) else ReadStatus()
                self.sink(self.setup.log_record(int(record[0]), record[1], record[2]), status)

    return FiveAxisRunRecorder


def build_five_axis_campaign_diagram(setup: FiveAxisCampaignSetup, station_factory=None, extend=None, sink=None):
    """The campaign as a Diagram on the station ``station_factory(builder, setup)`` adds (default: the simulated
    one); returns (diagram, recorder, sequencer); ``diagram.station`` is the station. ``extend(builder, setup=,
    station=, sequencer=, steering=, recorder=)`` adds systems before the diagram is built; ``sink(record,
    status)`` gets every reading (its log row)."""
    from olti_drake.sim.five_axis_station import AddFiveAxisStation, build_five_axis_diagram

    factory = station_factory or (lambda b, s: AddFiveAxisStation(b, s.run))
    hook = None if extend is None else (lambda b, station, seq, steer, rec: extend(
        b, setup=setup, station=station, sequencer=seq, steering=steer, recorder=rec))
    return build_five_axis_diagram(setup.run, lambda b, run: factory(b, setup), _recorder_class()(setup, sink), hook)


def five_axis_truth_result(setup: FiveAxisCampaignSetup, valid) -> dict:
    """The simulated truth (``olti simulate``'s truth.json) of a campaign with these ``valid`` flags."""
    from olti_drake.sim.five_axis_station import truth_dict

    return truth_dict(setup.run, int(np.sum(np.asarray(valid) > 0)))

