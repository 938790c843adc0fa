"""A laser tracker emulator speaking emScon bytes (:mod:`olti_drake.hardware.emscon`) on a local TCP port.

What it emulates (docs/tracker.md lists every number): a tracker whose beam goes where ``PointLaser`` or
``GoPosition`` sent it, and that measures the reflector at ``StartMeasurement`` only when the reflector's
centre lies within ``capture_mm`` of the beam line (the perpendicular distance at the reflector's distance,
in front of the tracker); otherwise it answers ``ES_RS_MeasurementStatusNotReady`` (10004) and sends no
result. The reflector is at rest (``reflector_mm``, tracker frame) or wherever ``reflector()`` says (the
simulated robot's true tool point, :func:`olti_drake.hardware.tracker_station.tracker_emulators_for`).

Seeded (``seed``; one generator, drawn in the same amounts at every StartMeasurement whatever its outcome):
the point's noise ~N(0, u(d)) per coordinate, u(d) = (``u_const_um`` + ``u_per_m_um`` · d[m]) / (k √3)
(the AT960 spec of 000 §4.3, as :class:`olti_drake.sim.tracker.LaserTrackerSpec`); beam breaks
(probability ``beam_break``: this measurement fails, the beam stays where it was pointed); a lost reflector
(probability ``reflector_lost``: the measurement fails and the beam is no longer on any point until the
next PointLaser/GoPosition); the environment's drift, a random walk of ``drift`` (°C, hPa, %RH) per
measurement from ``environment``.

Strict framing: a size field outside 12..MAX_PACKET loses the framing -- the server answers an
``ErrorResponseT`` (``ES_C_Unknown``, ``ES_RS_InvalidInputData``) and closes that connection; a packet of
another data type gets the same error and the connection goes on; an unknown command gets its
``BasicCommandRT`` with ``ES_RS_NotImplemented``; a known command of the wrong size or with a non-finite
parameter gets ``ES_RS_WrongParameter`` (…1..7 by the parameter); a packet cut short is dropped with the
connection (after ``PARTIAL_TIMEOUT_S``). A failure in one connection never stops the server.

Units: the session's (SetUnits; default mm, degrees, °C, hPa, %RH; metres and °F are honoured).
"""

from __future__ import annotations

import logging
import math
import select
import socket
import threading
from typing import Callable, Optional

import numpy as np

from olti_drake.hardware import emscon as E

_log = logging.getLogger(__name__)

#: Default reflector capture radius (mm): the ATR's lock-on range at the reflector.
CAPTURE_MM = 5.0
#: Seconds the server waits for the rest of a packet once its first byte came.
PARTIAL_TIMEOUT_S = 2.0
#: Default environment (°C, hPa, %RH) and its random walk per measurement.
ENVIRONMENT = (20.0, 1013.25, 45.0)
DRIFT = (0.01, 0.05, 0.1)
#: Farthest coordinate a PointLaser/GoPosition may name (mm): beyond any tracker's range.
MAX_RANGE_MM = 1e6
#: The environment a tracker accepts in SetEnvironmentParams (°C, hPa, %RH).
ENV_RANGE = ((-40.0, 60.0), (500.0, 1200.0), (0.0, 100.0))


class TrackerEmulator:
    """An emScon tracker on ``host``:``port`` (port 0: an ephemeral one, read :attr:`port` once started).

    ``reflector_mm``: a reflector at rest (tracker frame, mm), or ``reflector()``: its centre now (mm);
    ``initialized``: start as if Initialize had run (a real tracker needs it after power-up).
    Counters for tests: ``measurements`` (results sent), ``refused`` (StartMeasurement without one),
    ``bad_packets``.
    """

    def __init__(self, reflector_mm=None, *, reflector: Optional[Callable[[], np.ndarray]] = None, seed: int = 0,
                 capture_mm: float = CAPTURE_MM, u_const_um: float = 15.0, u_per_m_um: float = 6.0,
                 coverage_k: float = 2.0, beam_break: float = 0.0, reflector_lost: float = 0.0,
                 environment=ENVIRONMENT, drift=DRIFT, host: str = "127.0.0.1", port: int = 0,
                 initialized: bool = False):
        if (reflector_mm is None) == (reflector is None):
            raise ValueError("tracker emulator: give reflector_mm (at rest) or reflector() (carried), not both")
        fixed = None if reflector_mm is None else np.asarray(reflector_mm, float)
        if fixed is not None and (fixed.shape != (3,) or not np.all(np.isfinite(fixed))):
            raise ValueError(f"tracker emulator: reflector_mm must be 3 finite numbers (mm), got {reflector_mm!r}")
        for name, p in (("beam_break", beam_break), ("reflector_lost", reflector_lost)):
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"tracker emulator: {name} is a probability 0..1, got {p!r}")
        if not capture_mm > 0:
            raise ValueError(f"tracker emulator: capture_mm must be > 0, got {capture_mm!r}")
        self.reflector = reflector or (lambda: fixed)
        self.seed, self.capture_mm = int(seed), float(capture_mm)
        self.u = (float(u_const_um), float(u_per_m_um), float(coverage_k))
        self.beam_break, self.reflector_lost = float(beam_break), float(reflector_lost)
        self.env = np.array(environment, float)
        self.drift = np.array(drift, float)
        self.host, self._port = host, int(port)
        self.initialized = bool(initialized)
        self.units = E.UNITS_MM
        self.beam = None                       # unit vector of the beam (tracker frame), None: on no point
        self.measurements = self.refused = self.bad_packets = 0
        self._rng = np.random.default_rng(self.seed)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._server = None
        self._threads = []

    # ------------------------------------------------------------------ server

    @property
    def port(self) -> int:
        return self._server.getsockname()[1] if self._server is not None else self._port

    def start(self) -> "TrackerEmulator":
        self._server = socket.create_server((self.host, self._port))
        self._server.settimeout(0.1)
        t = threading.Thread(target=self._accept, name="tracker-emulator", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._server is not None:
            self._server.close()
        for t in self._threads:
            t.join(2.0)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            t.start()
            self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _serve(self, conn) -> None:
        with conn:
            while not self._stop.is_set():
                if not select.select([conn], [], [], 0.1)[0]:
                    continue
                try:
                    if not conn.recv(1, socket.MSG_PEEK):
                        return                         # the client closed between packets: no error
                    packet = E.read_packet(conn, PARTIAL_TIMEOUT_S)
                except E.EmsconError as e:     # cut short, closed, or a size field that loses the framing
                    self._count_bad()
                    if "framing lost" in str(e):
                        _send(conn, E.encode_error(E.C_UNKNOWN, E.RS_INVALID_INPUT_DATA))
                        _drain(conn)
                    return
                except OSError:
                    return
                try:
                    replies = self.handle(packet)
                except Exception:              # never let one request stop the server
                    _log.exception("tracker emulator: request failed")
                    replies = [E.encode_error(E.C_UNKNOWN, E.RS_INVALID_INPUT_DATA)]
                if not all(_send(conn, r) for r in replies):
                    return

    def _count_bad(self) -> None:
        with self._lock:
            self.bad_packets += 1

    # ------------------------------------------------------------------ requests

    def handle(self, packet: bytes) -> list:
        """The reply packets to one whole request packet."""
        try:
            command, params = E.decode_request(packet)
        except E.EmsconError as e:
            self._count_bad()
            if e.status == E.RS_INVALID_INPUT_DATA:
                return [E.encode_error(E.C_UNKNOWN, e.status)]
            return [E.encode_answer(int.from_bytes(packet[8:12], "little", signed=True), e.status)]
        with self._lock:
            if command not in (E.C_INITIALIZE, E.C_GET_UNITS, E.C_SET_UNITS) and not self.initialized:
                return [E.encode_answer(command, E.RS_TRACKER_NOT_INITIALIZED)]
            return getattr(self, "_" + E.NAMES[command])(command, params)

    def _Initialize(self, c, p):
        self.initialized, self.beam = True, None
        return [E.encode_answer(c, E.RS_ALL_OK)]

    def _SetUnits(self, c, p):
        allowed = ((E.LU_METER, E.LU_MILLIMETER), (E.AU_RADIAN, E.AU_DEGREE), (E.TU_CELSIUS, E.TU_FAHRENHEIT),
                   (E.PU_MBAR, E.PU_HPASCAL), (E.HU_RH,))
        for k, (v, ok) in enumerate(zip(p, allowed)):
            if v not in ok:
                return [E.encode_answer(c, E.RS_WRONG_PARAMETER1 + k)]
        self.units = tuple(p)
        return [E.encode_answer(c, E.RS_ALL_OK)]

    def _GetUnits(self, c, p):
        return [E.encode_answer(c, E.RS_ALL_OK, *self.units)]

    def _SetEnvironmentParams(self, c, p):
        env = self._env_from_session(p)
        for k, (v, (lo, hi)) in enumerate(zip(env, ENV_RANGE)):
            if not lo <= v <= hi:
                return [E.encode_answer(c, E.RS_WRONG_PARAMETER1 + k)]
        self.env = np.array(env)
        return [E.encode_answer(c, E.RS_ALL_OK)]

    def _GetEnvironmentParams(self, c, p):
        return [E.encode_answer(c, E.RS_ALL_OK, *self._env_to_session(self.env))]

    def _PointLaser(self, c, p):
        d = np.array(p[:3], float) * self._mm_per_unit()
        far = np.flatnonzero(np.abs(d) > MAX_RANGE_MM)
        if far.size:
            return [E.encode_answer(c, E.RS_WRONG_PARAMETER1 + int(far[0]))]
        n = float(np.linalg.norm(d))
        if n == 0.0:
            return [E.encode_answer(c, E.RS_WRONG_PARAMETER)]
        self.beam = d / n
        return [E.encode_answer(c, E.RS_ALL_OK)]

    _GoPosition = _PointLaser

    def _only(self, c, p, value):
        """Set a mode of which only ``value`` is implemented (stationary measurements, Cartesian RHR)."""
        return [E.encode_answer(c, E.RS_ALL_OK if p[0] == value else E.RS_WRONG_PARAMETER1)]

    def _SetMeasurementMode(self, c, p):
        return self._only(c, p, E.MM_STATIONARY)

    def _SetCoordinateSystemType(self, c, p):
        return self._only(c, p, E.CS_RHR)

    def _GetMeasurementMode(self, c, p):
        return [E.encode_answer(c, E.RS_ALL_OK, E.MM_STATIONARY)]

    def _GetCoordinateSystemType(self, c, p):
        return [E.encode_answer(c, E.RS_ALL_OK, E.CS_RHR)]

    def _StartMeasurement(self, c, p):
        rng = self._rng
        # The same draws whatever the outcome, so a seed gives one sequence of events.
        noise, u_break, u_lost = rng.standard_normal(3), rng.random(), rng.random()
        self.env = self.env + self.drift * rng.standard_normal(3)
        r = np.asarray(self.reflector(), float)
        beam = self.beam
        if u_lost < self.reflector_lost:
            self.beam = None
        if beam is None or u_lost < self.reflector_lost or u_break < self.beam_break or not self._captured(r, beam):
            self.refused += 1
            return [E.encode_answer(c, E.RS_MEAS_STATUS_NOT_READY)]
        d_m = float(np.linalg.norm(r)) * 1e-3
        u_const, u_per_m, k = self.u
        std = 1e-3 * (u_const + u_per_m * d_m) / (k * math.sqrt(3.0))
        point = r + std * noise
        pointing = r - (r @ beam) * beam       # where the beam was, seen from the reflector's centre
        f = 1.0 / self._mm_per_unit()
        stds = [std * f] * 3 + [std * f * math.sqrt(3.0)]
        values = [*(point * f), *stds, *(pointing * f), *stds, *self._env_to_session(self.env)]
        self.measurements += 1
        self.beam = point / np.linalg.norm(point)   # locked on: the beam follows the reflector's centre
        return [E.encode_answer(c, E.RS_ALL_OK), E.encode_result(values)]

    def _captured(self, r, beam) -> bool:
        along = float(r @ beam)
        return along > 0 and float(np.linalg.norm(r - along * beam)) <= self.capture_mm

    # ------------------------------------------------------------------ units

    def _mm_per_unit(self) -> float:
        return 1000.0 if self.units[0] == E.LU_METER else 1.0

    def _env_to_session(self, env) -> tuple:
        t, p, h = (float(v) for v in env)
        return (t * 9.0 / 5.0 + 32.0 if self.units[2] == E.TU_FAHRENHEIT else t, p, h)   # mbar = hPa

    def _env_from_session(self, env) -> tuple:
        t, p, h = env
        return ((t - 32.0) * 5.0 / 9.0 if self.units[2] == E.TU_FAHRENHEIT else t, p, h)


def _drain(conn, seconds: float = 0.2) -> None:
    """Close our side and read what the peer still sends for a moment, so that the error we sent is not
    thrown away by a reset (closing a socket with unread input resets the connection)."""
    try:
        conn.shutdown(socket.SHUT_WR)
        while select.select([conn], [], [], seconds)[0] and conn.recv(4096):
            pass
    except OSError:
        pass


def _send(conn, data: bytes) -> bool:
    try:
        conn.sendall(data)
        return True
    except OSError:
        return False
