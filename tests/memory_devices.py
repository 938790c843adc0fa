"""Drivers of an in-memory robot and counter: a device family added by writing its driver classes.

They speak no serial protocol at all -- the point is that the hardware station needs nothing but
the driver methods (olti_drake.hardware.drivers). The truth is the noise-free simulated robot of
``MemoryRobot.setup`` (set by the test), and the counter is zeroed like the emulator's.
"""

import numpy as np

from olti_drake.model.errormap import approach_directions
from olti_drake.model.instrument import beam_geometry
from olti_drake.hardware.protocol import Joints, Position, Reading


class MemoryRobot:
    setup = None          # a campaign Setup, set by the test
    opened = []

    def __init__(self):
        self.command, self.directions = np.full(4, np.nan), np.ones(4)
        MemoryRobot.opened.append(self)

    @classmethod
    def open(cls, port, baud, timeout_s, retries):
        return cls()

    def move(self, command):
        command = np.asarray(command, dtype=float)
        self.directions = approach_directions(command[None], self.command, self.directions)[0]
        self.command = command

    def wait(self, max_ms):
        pass

    def position(self):
        j = Joints(*self.command)
        return Position(j, j)

    def alarms(self, clear=False):
        return ()

    def close(self):
        pass


class MemoryCounter:
    def __init__(self):
        self.reflector, self.zero_mm = 0, None

    @classmethod
    def open(cls, port, baud, timeout_s, retries):
        return cls()

    def _length(self):
        robot = MemoryRobot.opened[-1]
        setup = MemoryRobot.setup
        c, d = robot.command, robot.directions
        origin, angle = setup.robot.laser_beam(c[0:1], c[1:2], c[3:4], d[0], d[1], d[3])
        along, _ = beam_geometry(origin[0], float(angle[0]), setup.reflectors_mm[self.reflector])
        return float(along)

    def set_up_reflector(self, j):
        self.reflector, self.zero_mm = int(j), None

    def zero(self):
        self.zero_mm = self._length()
        return True

    def read(self):
        if self.zero_mm is None:
            return Reading(0.0, False, "NOT-ZEROED")
        return Reading(self._length() - self.zero_mm, True, "OK")

    def close(self):
        pass
