"""What the hardware-run tests read back from a run directory (``olti run --out DIR``) and how they call the
``olti`` command in-process (:func:`olti_here`, the suite's one in-process call, :func:`olti_calls.olti_in`): one
copy for every station kind's run tests."""

import json
import os
import subprocess
import sys
import time

from olti_drake.io.csvio import read_table
from olti_calls import olti_in

olti_here = olti_in   # (exit code, stdout, stderr) of olti ARGV in this process


def run_table(out, columns):
    """The run's ``campaign.csv`` (its log) with ``columns``."""
    return read_table(os.path.join(out, "campaign.csv"), columns)


def run_events(out) -> list:
    """The run's ``events.jsonl``, one dict per event."""
    with open(os.path.join(out, "events.jsonl"), encoding="utf-8") as f:
        return [json.loads(line) for line in f]


def readings_on_disk(out) -> int:
    """Complete reading lines of the run's log on disk (after its 2 comment lines and the header; 0 before it
    exists): a line cut short by a kill is not counted."""
    csv = os.path.join(out, "campaign.csv")
    return open(csv, "rb").read().count(b"\n") - 3 if os.path.exists(csv) else 0


def kill_twice(scenario, out, rng, planned: int, cut_s: float, cwd=None) -> None:
    """``olti run`` in a subprocess SIGKILLed at a seeded random reading count (10..39 more on disk) and a seeded
    delay below ``cut_s`` s (a line may be cut short), then again after ``--resume``: each time it must have been
    killed (not ended), with 10 .. ``planned`` - 1 readings on disk."""
    for extra in ([], ["--resume"]):
        wanted = readings_on_disk(out) + int(rng.integers(10, 40))
        proc = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "run", scenario, "--out", out, *extra],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and readings_on_disk(out) < wanted:
            time.sleep(0.002)
        time.sleep(float(rng.uniform(0.0, cut_s)))     # anywhere in the next reading
        proc.kill()                                    # SIGKILL: no clean-up of any kind
        proc.wait(10)
        assert proc.returncode == -9, "the run ended before it was killed"
        assert 10 <= readings_on_disk(out) < planned
