"""The MathematicalProgram example: user constraints and costs take effect."""

import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_constraints_and_smoothness_prior_take_effect():
    r = subprocess.run([sys.executable, os.path.join(ROOT, "examples", "identify_with_constraints.py")],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    rows = {line.split()[0]: line for line in r.stdout.splitlines()}
    curv = {k: float(re.search(r"curvature ([\d.]+)", v).group(1)) for k, v in rows.items()}
    l1 = {k: float(re.search(r"L1 = ([\d.]+)", v).group(1)) for k, v in rows.items()}
    assert l1["constrained"] == 325.0 and l1["plain"] != 325.0
    assert curv["constrained"] < 0.1 * curv["plain"]
