"""Device emulator of a 3-axis machine tool and its pan/tilt interferometer heads, on pseudo-terminals.

The 3D machine counterpart of :class:`~olti_drake.hardware.serial_emulator.SerialEmulator`
(docs/emulator.md, "3D machine tools"), speaking the same protocol version 2 (docs/protocol.md,
"N-axis devices and pan/tilt heads"), one line per device:

- ``robot`` (``PONG,2,ROBOT,XYZ-EMU``): the machine's controller, ``MOVJ WAIT POSJ ALRM INFO`` with
  three linear axes announced as ``X``, ``Y``, ``Z`` (mm, limits = the travel); the controller logic
  (limits, realistic motion, encoders, alarms) is the SCARA emulator's;
- ``head0`` ... ``head<K-1>`` (``PONG,2,HEAD,TRACER-EMU``): a pan/tilt head with its counter, ``AIM
  WAIT POSH READ ZERO INFO``, as the N-joint emulator's tracer heads.

The truth is the 3D campaign's own (:func:`~olti_drake.model.machine.machine_run_3d` of the scenario:
the volumetric3d error motions, the true head centres and zeros, the heads' angular error), so the
emulator reads what the simulated station of :mod:`olti_drake.sim.machine3d_station` reads: the beam
leaves the TRUE head centre along command + head error + true zeros and reads the TRUE tool point
(:func:`~olti_drake.model.volumetric3d.tool_positions` at the axes' position) by
:func:`~olti_drake.model.aiming3d.read_beam` (cosine error, acceptance, budget noise with the pose
term on the head, λ/64). The spindle carries a cat's eye in every mounting the scenario measures
(``tools``): a head reads the one its beam meets (the least miss), so the aim selects the tool and
no tool change is needed. Faults are the base class's, from the same seeded streams.

Units: mm and degrees, as on the wire.
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np

from olti_drake.hardware.emulator import DEFAULT_SETTLE_S
from olti_drake.hardware.protocol import Axis, AxisLayout
from olti_drake.hardware.serial_emulator import SerialEmulator
from olti_drake.model.aiming3d import PanTiltHeads, beam_geometry_3d, pan_tilt_beam, read_beam
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.sim.scenario import stream_rng

#: Axis speed of the realistic mode (mm/s) and the encoder resolution (mm) of the machine's scales.
DEFAULT_AXIS_SPEED_MM_S = 100.0
DEFAULT_AXIS_RESOLUTION_MM = 1e-4
AXES = ("X", "Y", "Z")


def machine_layout(config) -> AxisLayout:
    """The machine's axes as its controller announces them: X, Y, Z in mm, limits = the travel."""
    return AxisLayout(tuple(Axis(a, "mm", float(min(config.travel_mm[a])), float(max(config.travel_mm[a])))
                            for a in AXES))


class Machine3DEmulator(SerialEmulator):
    """A 3-axis machine controller and ``K`` pan/tilt heads on ``1 + K`` pseudo-terminals.

    Args:
        scenario: a :class:`~olti_drake.model.machine.Machine3DScenario` (the model layer's: machine,
            grid, tools, heads, seeds, interferometer switches).
        run: its planned :class:`~olti_drake.model.machine.Machine3DRun` (None: drawn from the
            scenario by ``machine_run_3d``, as the simulated station does).
        budget: the reading uncertainty budget (None: no noise).
        seed: noise and fault seed (``emulator_noise``, ``emulator_faults`` per line).
        speed, faults, link, latch_beam_loss, clock, fault switches: as
            :class:`~olti_drake.hardware.emulator.Emulator`.
        speeds (mm/s), settle_s, encoder_resolution (mm), home (mm; default the travel's start):
            per axis; scalars broadcast.

    ``robot_port`` and ``head_ports`` are the device paths once started; ``run`` is the truth.
    """

    def __init__(self, scenario, *, run=None, budget=None, seed: int = 0, speed: str = "fast", faults=None,
                 speeds=DEFAULT_AXIS_SPEED_MM_S, settle_s: float = DEFAULT_SETTLE_S,
                 encoder_resolution=DEFAULT_AXIS_RESOLUTION_MM, home=None, link: Optional[str] = None,
                 latch_beam_loss: bool = False, models=("XYZ-EMU", "TRACER-EMU"), clock=time.monotonic,
                 **fault_switches):
        from olti_drake.model.machine import machine_run_3d

        self._init_lines(speed, faults, fault_switches, link, latch_beam_loss, models, clock)
        self.scenario = scenario
        self.run = run if run is not None else machine_run_3d(scenario)
        self.seed, self.truth_seed = int(seed), int(scenario.truth_seed)
        self.config, self.truth = self.run.config, self.run.truth
        self.tools = np.array(sorted(set(int(t) for t in scenario.tools)), dtype=int)
        self.catseye_axis = np.asarray(scenario.catseye_axis, float)
        self.options = scenario.interferometer or InterferometerOptions()
        self.budget = budget
        self._noise = stream_rng(self.seed, "emulator_noise")
        layout = machine_layout(self.config)
        start = [float(self.config.travel_mm[a][0]) for a in AXES]    # the travel's start: the reference
        self._init_robot(layout, [(a.lower, a.upper) for a in layout.axes], np.broadcast_to(speeds, 3), settle_s,
                         np.broadcast_to(encoder_resolution, 3), start if home is None else np.broadcast_to(home, 3))
        heads = self.run.heads_true
        self._init_heads(heads, [self.run.head_error] * len(heads.centres_mm))

    def actual_angles(self):
        raise AttributeError("a 3D machine emulator has no joint angles: see tool_points_mm()")

    def tool_points_mm(self) -> np.ndarray:
        """The true cat's-eye centres now (len(tools), 3) mm: the tool point of every mounting at the axes'
        position (the volumetric error motions composed)."""
        from olti_drake.model.volumetric3d import tool_positions

        with self._lock:
            q = self._position(self.clock())
        return tool_positions(self.config, self.truth, np.repeat(q[None], len(self.tools), axis=0), self.tools)

    def head_reading(self, h: int, dead_path_mm: float, options: InterferometerOptions, rng=None):
        """What head ``h`` reads now: (reading mm, beam returned), from the cat's eye its beam meets."""
        with self._lock:
            points = self.tool_points_mm()
            heads = PanTiltHeads(self.heads_true.centres_mm[h], self.heads_true.zeros_deg[h])
            origin, u = pan_tilt_beam(heads, [0], self._heads[h].command[None], self.head_errors[h])
            _, miss = beam_geometry_3d(np.broadcast_to(origin, points.shape), np.broadcast_to(u, points.shape),
                                       points)
            target = points[int(np.argmin(miss))]
            r = read_beam(origin, u, target[None], self.catseye_axis, [dead_path_mm], options, self.budget, rng,
                          pose_noise_on="origin")   # 001: the noise of the head's axes
            return float(r.reading_mm[0]), bool(r.valid[0])
