"""Device emulator of an N-joint serial robot and its floor tracer stations, on pseudo-terminals.

The N-joint counterpart of :class:`~olti_drake.hardware.emulator.Emulator` (docs/emulator.md,
"N-joint robots"), speaking protocol version 2 (docs/protocol.md, "N-axis devices and pan/tilt
heads"). One line per device, as the real bench has one adapter per device:

- ``robot`` (``PONG,2,ROBOT,<model>``): ``MOVJ WAIT POSJ ALRM INFO`` with one field per joint of the
  model file; the controller logic (limits, approach directions, realistic motion, encoders, alarms)
  is the SCARA emulator's, parameterized by the joint count;
- ``head0`` ... ``head<K-1>`` (``PONG,2,HEAD,TRACER-EMU``): a pan/tilt head with its interferometer
  counter: ``AIM WAIT POSH READ ZERO INFO``. Heads turn at once (in ``realistic`` mode too).

The truth is not reimplemented here: the chain is :func:`~olti_drake.model.chain.load_serial_chain`
of the model file, the robot :func:`~olti_drake.model.serial.synthetic_truth` (location errors,
joint deviations with backlash, station positions), the beams and readings
:func:`~olti_drake.model.aiming3d.head_readings` (pan/tilt heads and ``read_beam``: cosine error,
beam loss, budget noise, λ/64). Faults (latency, lost, garbled, cut frames, NAK CRC, beam loss,
alarm, disconnect) are the base class's, from the same seeded streams.

Units: mm and degrees, as on the wire.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path
from typing import Optional

import numpy as np

from olti_drake.hardware.emulator import DEFAULT_SETTLE_S, Emulator, counter_reply
from olti_drake.hardware.protocol import (NJ_PROTOCOL_VERSION, PAN_TILT_LAYOUT, Axis, AxisLayout, Frame, NakError,
                                          axis_fields, decode_info_request, decode_vector, decode_wait, info_fields,
                                          position_fields)
from olti_drake.model.aiming3d import PanTiltHeads, harmonic_head_error, head_readings
from olti_drake.model.chain import UNLIMITED_RANGE_DEG, load_serial_chain
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model.serial import synthetic_truth
from olti_drake.sim.scenario import stream_rng, stream_seed

#: Robots known by name: model file (in olti_drake/models) and tool frame.
ROBOTS = {"ur5": ("ur5.urdf", "tool0")}
NJ_ROBOT_VERBS = ("PING", "MOVJ", "WAIT", "POSJ", "ALRM", "INFO")
HEAD_VERBS = ("PING", "AIM", "WAIT", "POSH", "READ", "ZERO", "INFO")
#: Joint speed of the realistic mode (deg/s) and encoder resolution (deg, 2^20 counts/rev).
DEFAULT_JOINT_SPEED = 60.0
DEFAULT_JOINT_RESOLUTION = 360.0 / 2 ** 20
#: Standard deviation of the heads' true zero angles (deg) and amplitude of their angular error (mdeg).
HEAD_ZERO_SIGMA_DEG = 0.2
HEAD_ERROR_MDEG = 2.0


def load_robot(robot, tool_frame: Optional[str] = None):
    """The :class:`~olti_drake.model.chain.SerialChain` of a robot name (``ROBOTS``) or model file.

    A model file needs ``tool_frame``; a name or path that does not load is a one-line ValueError."""
    if isinstance(robot, str) and robot in ROBOTS:
        file, frame = ROBOTS[robot]
        return load_serial_chain(Path(__file__).resolve().parents[1] / "models" / file, tool_frame or frame)
    if tool_frame is None:
        raise ValueError(f"robot {robot!r}: not one of {', '.join(ROBOTS)}; a model file needs its tool frame")
    return load_serial_chain(robot, tool_frame)


def chain_layout(chain) -> AxisLayout:
    """The robot's axes as the protocol announces them: joint names, deg, the model's limits
    (±UNLIMITED_RANGE_DEG for a continuous joint)."""
    lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -UNLIMITED_RANGE_DEG)
    hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, UNLIMITED_RANGE_DEG)
    return AxisLayout(tuple(Axis(name, "deg", float(a), float(b)) for name, a, b in zip(chain.joint_names, lo, hi)))


@dataclasses.dataclass
class _Head:
    """One tracer head: its pan/tilt command (deg) and its counter's state (as the SCARA counter's)."""
    command: np.ndarray
    _zeroed: bool = False
    _count_lost: bool = False
    _last_value: float = 0.0
    dead_path: float = math.nan


class SerialEmulator(Emulator):
    """An N-joint robot controller and ``K`` tracer heads on ``1 + K`` pseudo-terminals.

    Args:
        robot: a name of ``ROBOTS`` (``"ur5"``) or a URDF/SDFormat file (then ``tool_frame``).
        truth: a :class:`~olti_drake.model.serial.SyntheticTruth` (or anything with ``chain``,
            ``chain_params``, ``actual_angles``, ``stations_mm``); None draws
            ``synthetic_truth(chain, seed)`` from the ``emulator_truth`` stream of ``truth_seed``.
        heads_true: :class:`~olti_drake.model.aiming3d.PanTiltHeads`; None: the truth's stations,
            zero angles ~N(0, HEAD_ZERO_SIGMA_DEG) (``emulator_truth`` stream of ``truth_seed``).
        head_error_mdeg: amplitude of each head's angular positioning error
            (``harmonic_head_error``, seeded per head from ``truth_seed``); 0: none.
        head_errors: the heads' angular error functions (one per head, None: none), instead.
        seed: noise and fault seed (``emulator_noise``, ``emulator_faults`` per line).
        catseye_axis_tool: the cat's-eye axis in the tool frame; ``options``, ``budget``: the
            interferometer's switches and uncertainty budget (None: no noise).
        speed, faults, link, latch_beam_loss, clock, fault switches: as :class:`Emulator`.
        speeds, settle_s, encoder_resolution, home: per joint (deg); scalars broadcast.

    ``robot_port`` and ``head_ports`` are the device paths once started; ``heads_true``,
    ``head_error`` and ``truth`` are the simulated truth (for tests and for exact steering).
    """

    def __init__(self, robot="ur5", *, tool_frame: Optional[str] = None, truth=None, truth_seed: int = 0,
                 seed: int = 0, heads_true: Optional[PanTiltHeads] = None, head_error_mdeg: float = HEAD_ERROR_MDEG,
                 head_errors=None,
                 catseye_axis_tool=(0.0, 0.0, 1.0), options: Optional[InterferometerOptions] = None, budget=None,
                 speed: str = "fast", faults=None, speeds=DEFAULT_JOINT_SPEED, settle_s: float = DEFAULT_SETTLE_S,
                 encoder_resolution=DEFAULT_JOINT_RESOLUTION, home=0.0, link: Optional[str] = None,
                 latch_beam_loss: bool = False, models=None, clock=time.monotonic, **fault_switches):
        chain = truth.chain if truth is not None else load_robot(robot, tool_frame)
        model = (robot if isinstance(robot, str) and robot in ROBOTS else Path(str(robot)).stem)
        self._init_lines(speed, faults, fault_switches, link, latch_beam_loss,
                         models or (f"{model.upper()[:24]}-EMU", "TRACER-EMU"), clock)
        self.seed, self.truth_seed = int(seed), int(truth_seed)
        self.truth = truth if truth is not None else synthetic_truth(chain, stream_seed(truth_seed, "emulator_truth"))
        n, k = chain.n_joints, len(self.truth.stations_mm)
        if heads_true is None:
            zeros = stream_rng(truth_seed, "emulator_truth", 1).normal(0.0, HEAD_ZERO_SIGMA_DEG, (k, 2))
            heads_true = PanTiltHeads(self.truth.stations_mm, zeros)
        head_errors = list(head_errors) if head_errors is not None else [
            harmonic_head_error(stream_seed(truth_seed, "emulator_truth", 2, h), head_error_mdeg)
            if head_error_mdeg else None for h in range(len(heads_true.centres_mm))]
        self.catseye_axis_tool = np.asarray(catseye_axis_tool, float)
        self.options = options or InterferometerOptions()
        self.budget = budget
        self._noise = stream_rng(self.seed, "emulator_noise")
        layout = chain_layout(chain)
        limits = [(a.lower, a.upper) for a in layout.axes]
        self._init_robot(layout, limits, np.broadcast_to(speeds, n), settle_s, np.broadcast_to(encoder_resolution, n),
                         np.broadcast_to(home, n))
        self._init_heads(heads_true, head_errors)

    def _init_heads(self, heads_true: PanTiltHeads, head_errors) -> None:
        """The head lines (after ``_init_robot``): true centres and zeros, each head's angular error
        function (or None), the pan/tilt layout, the lines' roles, the counters' state."""
        self.heads_true = heads_true
        self.head_errors = list(head_errors)
        self.head_layout = PAN_TILT_LAYOUT
        self.roles = ("robot",) + tuple(f"head{h}" for h in range(len(heads_true.centres_mm)))
        self._heads = [_Head(np.zeros(2)) for _ in range(len(heads_true.centres_mm))]
        #: The heads' encoder resolution (deg): the robot's default, 0 (exact) when the robot's is.
        self.head_resolution = DEFAULT_JOINT_RESOLUTION if np.any(self.encoder_resolution > 0) else 0.0

    # ------------------------------------------------------------------ lines

    def _line_spec(self, role: str):
        if role == "robot":
            return NJ_ROBOT_VERBS, "ROBOT", self.models[0], NJ_PROTOCOL_VERSION
        return HEAD_VERBS, "HEAD", self.models[1], NJ_PROTOCOL_VERSION

    def _verb(self, role: str, verb: str):
        if role == "robot":
            return getattr(self, "on_" + verb)
        return functools.partial(getattr(self, "head_" + verb), int(role[4:]))

    def _command(self, frame: Frame) -> np.ndarray:
        # The range is checked after the alarm, as for the SCARA (NAK,RANGE, not SYN).
        return np.array(decode_vector(frame, self.layout, slack=math.inf))

    @property
    def head_ports(self) -> list:
        """The heads' device paths (pty slaves), head 0 first."""
        return [self._lines[role].path for role in self.roles[1:]]

    @property
    def counter_port(self) -> str:
        raise AttributeError("an N-joint emulator has no counter line: each head has its own (head_ports)")

    # ------------------------------------------------------------------ robot

    def on_INFO(self, frame: Frame):
        return _info(frame, self.layout)

    def actual_angles(self) -> np.ndarray:
        """The robot's actual joint angles now (deg): the truth's deviations at the current position."""
        with self._lock:
            return self.truth.actual_angles(self._position(self.clock())[None], self._direction[None])[0]

    # ------------------------------------------------------------------ heads

    def head_INFO(self, h: int, frame: Frame):
        return _info(frame, self.head_layout)

    def head_AIM(self, h: int, frame: Frame):
        cmd = np.array(decode_vector(frame, self.head_layout, "AIM", slack=math.inf))
        why = self.head_layout.outside(cmd)
        if why:
            raise NakError("RANGE", why)
        with self._lock:
            self._heads[h].command = cmd
        return ("ACK",)

    def head_WAIT(self, h: int, frame: Frame):
        decode_wait(frame)
        return ("ACK",)       # heads turn at once

    def head_POSH(self, h: int, frame: Frame):
        _no_fields(frame)
        with self._lock:
            cmd = self._heads[h].command
            res = self.head_resolution
            enc = np.round(cmd / res) * res if res > 0 else cmd
            return ("HPOS", *position_fields(cmd, enc, self.head_layout, "HPOS"))

    def head_reading(self, h: int, dead_path_mm: float, options: InterferometerOptions, rng=None):
        """What head ``h`` reads now: (reading mm, beam returned) for the given dead path and options."""
        with self._lock:
            q = self._position(self.clock())
            r = head_readings(self.truth, q[None], self._direction[None], [0], self._heads[h].command[None],
                              PanTiltHeads(self.heads_true.centres_mm[h], self.heads_true.zeros_deg[h]),
                              [dead_path_mm], catseye_axis_tool=self.catseye_axis_tool,
                              head_error=self.head_errors[h], options=options, budget=self.budget, rng=rng)
            return float(r.reading_mm[0]), bool(r.valid[0])

    def head_READ(self, h: int, frame: Frame):
        _no_fields(frame)
        forced = getattr(self._tls, "forced_beam_loss", False)
        with self._lock:
            head = self._heads[h]
            reading, ok = self.head_reading(h, head.dead_path if head._zeroed else 0.0, self.options, self._noise)
            return counter_reply(head, reading, ok, forced, self.latch_beam_loss)

    def head_ZERO(self, h: int, frame: Frame):
        _no_fields(frame)
        with self._lock:
            length, ok = self.head_reading(h, 0.0, dataclasses.replace(self.options, noise=False, quantization=False))
            if self.options.beam_loss and not ok:
                raise NakError("BEAM", "no beam at the receiver")
            head = self._heads[h]
            head.dead_path, head._zeroed, head._count_lost, head._last_value = length, True, False, 0.0
        return ("ACK",)

    @property
    def head_dead_paths_mm(self) -> tuple:
        """Each head's counter zero: the optical length at its last ZERO (NaN before any)."""
        with self._lock:
            return tuple(h.dead_path for h in self._heads)


def _no_fields(frame: Frame) -> None:
    if frame.fields:
        raise NakError("SYN", f"expects 0 fields; got {len(frame.fields)}")


def _info(frame: Frame, layout: AxisLayout):
    """INFO -> INF,<n>; INFO,<k> -> AXS,<k>,... (NAK,RANGE beyond the last axis)."""
    k = decode_info_request(frame)
    if k is None:
        return ("INF", *info_fields(layout.n))
    if k >= layout.n:
        raise NakError("RANGE", f"axis {k} outside 0..{layout.n - 1}")
    return ("AXS", *axis_fields(k, layout.axes[k]))
