"""Device emulator of a five-axis machine tool and its pan/tilt interferometer heads, on pseudo-terminals.

The five-axis counterpart of :class:`~olti_drake.hardware.machine3d_emulator.Machine3DEmulator` (docs/emulator.md,
"Five-axis machine tools"), speaking the same protocol version 2 (docs/protocol.md, "N-axis devices and pan/tilt
heads"), one line per device:

- ``robot`` (``PONG,2,ROBOT,XYZAC-EMU`` on the A/C trunnion): the machine's controller, ``MOVJ WAIT POSJ ALRM
  INFO``, its axes the model file's in its order (``X``, ``Y``, ``Z`` in mm, the rotary letters in deg; limits = the
  travel); the controller logic (limits, approach directions by the formats.md rule, realistic motion, encoders,
  alarms) is the SCARA emulator's;
- ``head0`` ... ``head<K-1>`` (``PONG,2,HEAD,TRACER-EMU``): the pan/tilt heads, station order (the bed's, then the
  table's), as the N-joint emulator's tracer heads.

The truth is the scenario's planned run (:func:`~olti_drake.sim.five_axis_station.prepare_five_axis`): the error
truth (location errors, bidirectional error motions of the rotary axes -- the emulator's own approach directions
select forward or reverse --, the linear axes' errors), the heads' true centres, zeros and angular error. Head j
reads as the simulated station does: its beam leaves the TRUE centre along command + head error + true zeros, in its
station's frame (a head on the table lives in the workpiece frame and turns with it), and reads the TRUE tool point
in that frame by :func:`~olti_drake.model.aiming3d.read_beam` (cosine error, acceptance, budget noise with the pose
term on the head, λ/64), the cat's eye's axis from the commanded pose. The spindle carries a cat's eye in every
mounting (``tool_offsets_mm``): a head reads the one its beam meets (the least miss), so the aim selects the tool.
Faults are the base class's, from the same seeded streams.

The R-test device is not emulated: a head's READ carries one displacement (``DIS``), the protocol has no reply
for the R-test's three; R-test paths are simulated (``olti simulate``) only.

Units: mm and degrees, as on the wire.
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np

from olti_drake.hardware.emulator import DEFAULT_SETTLE_S
from olti_drake.hardware.machine3d_emulator import DEFAULT_AXIS_RESOLUTION_MM, DEFAULT_AXIS_SPEED_MM_S
from olti_drake.hardware.protocol import Axis, AxisLayout
from olti_drake.hardware.serial_emulator import DEFAULT_JOINT_RESOLUTION, DEFAULT_JOINT_SPEED, SerialEmulator
from olti_drake.model.aiming3d import PanTiltHeads, beam_geometry_3d, pan_tilt_beam, read_beam
from olti_drake.sim.scenario import stream_rng

LINEAR = "XYZ"


def axis_unit(letter: str) -> str:
    """The wire unit of a machine axis: mm for X, Y, Z, deg for a rotary letter."""
    return "mm" if letter in LINEAR else "deg"


def machine5_layout(machine) -> AxisLayout:
    """The machine's axes as its controller announces them: the model file's letters in its order, mm / deg,
    limits = the travel to the wire's 6 decimals (a model file's -120° read back from radians is
    -119.99999999999999)."""
    return AxisLayout(tuple(Axis(a, axis_unit(a), round(float(lo), 6), round(float(hi), 6))
                            for a, lo, hi in zip(machine.axes, machine.lower, machine.upper)))


def _per_axis(machine, linear, rotary) -> np.ndarray:
    return np.array([linear if a in LINEAR else rotary for a in machine.axes], float)


class Machine5Emulator(SerialEmulator):
    """A five-axis machine controller and ``K`` pan/tilt heads on ``1 + K`` pseudo-terminals.

    Args:
        run: the planned :class:`~olti_drake.sim.five_axis_station.FiveAxisRun` (machine, truth, heads, head error,
            tools, cat's eye, interferometer options, budget) -- the truth the simulated station reads.
        seed: noise and fault seed (``emulator_noise``, ``emulator_faults`` per line).
        noise: read with the run's budget when its options say ``noise`` (False: no noise whatever they say).
        speed, faults, link, latch_beam_loss, clock, fault switches: as
            :class:`~olti_drake.hardware.emulator.Emulator`.
        speeds (mm/s, deg/s), encoder_resolution (mm, deg): per axis, None = the linear / rotary defaults;
        settle_s; home (mm/deg; default 0 clipped to the travel).

    ``robot_port`` and ``head_ports`` are the device paths once started.
    """

    def __init__(self, run, *, seed: int = 0, noise: bool = True, speed: str = "fast", faults=None, speeds=None,
                 settle_s: float = DEFAULT_SETTLE_S, encoder_resolution=None, home=None,
                 link: Optional[str] = None, latch_beam_loss: bool = False, models=None, clock=time.monotonic,
                 **fault_switches):
        m = run.machine
        self._init_lines(speed, faults, fault_switches, link, latch_beam_loss,
                         models or ("".join(m.axes) + "-EMU", "TRACER-EMU"), clock)
        self.run, self.machine, self.truth = run, m, run.truth
        self.seed, self.truth_seed = int(seed), int(run.scenario.truth.seed)
        self.frames = tuple(run.plan.station_frames)
        self.n_tools = len(run.tool_offsets_mm)
        self.catseye_axis_tool = np.asarray(run.catseye_axis_tool, float)
        self.options = run.options
        self.budget = run.budget if noise else None
        self._rotary = [m.axes.index(a) for a in m.rotary]
        self._noise = stream_rng(self.seed, "emulator_noise")
        layout = machine5_layout(m)
        n = layout.n
        speeds = _per_axis(m, DEFAULT_AXIS_SPEED_MM_S, DEFAULT_JOINT_SPEED) if speeds is None else speeds
        res = (_per_axis(m, DEFAULT_AXIS_RESOLUTION_MM, DEFAULT_JOINT_RESOLUTION) if encoder_resolution is None
               else encoder_resolution)
        start = np.clip(0.0, m.lower, m.upper) if home is None else home
        self._init_robot(layout, [(a.lower, a.upper) for a in layout.axes], np.broadcast_to(speeds, n), settle_s,
                         np.broadcast_to(res, n), np.broadcast_to(start, n))
        self._init_heads(run.heads_true, [run.head_error] * len(run.heads_true.centres_mm))

    def actual_angles(self):
        raise AttributeError("a five-axis machine emulator has no joint angles: see tool_points_mm()")

    def tool_points_mm(self, frame: str = "workpiece") -> np.ndarray:
        """The true cat's-eye centres now (n_tools, 3) mm in ``frame`` (``base`` / ``workpiece``): every mounting's
        tool point at the axes' position, approached as the controller last moved each rotary axis."""
        with self._lock:
            q, d = self._position(self.clock()), self._direction[self._rotary]
        k = self.n_tools
        return self.truth.truth_positions(np.repeat(q[None], k, 0), np.repeat(d[None], k, 0), np.arange(k), frame)

    def head_reading(self, h: int, dead_path_mm: float, options, rng=None):
        """What head ``h`` reads now: (reading mm, beam returned), from the cat's eye its beam meets, in its
        station's frame."""
        with self._lock:
            frame = self.frames[h]
            points = self.tool_points_mm(frame)
            T = self.machine.transforms(self._position(self.clock())[None], frame)[0]
            heads = PanTiltHeads(self.heads_true.centres_mm[h], self.heads_true.zeros_deg[h])
            origin, u = pan_tilt_beam(heads, [0], self._heads[h].command[None], self.head_errors[h])
            _, miss = beam_geometry_3d(np.broadcast_to(origin, points.shape), np.broadcast_to(u, points.shape),
                                       points)
            r = read_beam(origin, u, points[int(np.argmin(miss))][None], T[:3, :3] @ self.catseye_axis_tool,
                          [dead_path_mm], options, self.budget, rng, pose_noise_on="origin")  # 001: the head's noise
            return float(r.reading_mm[0]), bool(r.valid[0])
