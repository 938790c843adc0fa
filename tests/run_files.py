"""What the hardware-run tests read back from a run directory (``olti run --out DIR``) and how they call the
``olti`` command in-process: one copy for every station kind's run tests."""

import contextlib
import io
import json
import os

from olti_drake.io.csvio import read_table


def run_table(out, columns):
    """The run's ``campaign.csv`` (its log) with ``columns``."""
    return read_table(os.path.join(out, "campaign.csv"), columns)


def run_events(out) -> list:
    """The run's ``events.jsonl``, one dict per event."""
    with open(os.path.join(out, "events.jsonl"), encoding="utf-8") as f:
        return [json.loads(line) for line in f]


def olti_here(*argv):
    """The olti command in this process: (exit code, stdout, stderr)."""
    from olti_drake.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()
