"""Docs that quote numbers keep them (issue 24, class 9): the figures `docs/six_axis_campaign.md` quotes for the
shipped six-axis scenario are the ones `olti demo --robot six_axis` prints (read from the doc's sentence, so an
edit of either side that lets them drift fails here). The tutorial's quoted outputs have their own test
(tests/test_tutorial.py)."""

import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _quoted():
    """The six-axis doc's figures, µm: residual RMS of dh and errormap, unseen RMS / max of nominal, dh, errormap."""
    with open(os.path.join(ROOT, "docs", "six_axis_campaign.md"), encoding="utf-8") as f:
        text = " ".join(f.read().split())
    m = re.search(r"residual RMS ([\d.]+) µm \(dh\) and ([\d.]+) µm \(errormap.*?nominal RMS (\d+) µm / max (\d+) µm, "
                  r"dh (\d+) / (\d+) µm, errormap (\d+) / (\d+) µm", text)
    assert m, "docs/six_axis_campaign.md: the sentence with the shipped scenario's figures is gone"
    v = [float(g) for g in m.groups()]
    return {"dh": v[0], "errormap": v[1]}, {"nominal": v[2:4], "dh": v[4:6], "errormap": v[6:8]}


def test_the_six_axis_doc_quotes_what_the_demo_prints(tmp_path):
    residual, unseen = _quoted()
    run = subprocess.run([sys.executable, "-m", "olti_drake.cli", "demo", "--robot", "six_axis", "--out",
                          str(tmp_path / "demo")], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    printed = [float(v) for v in re.findall(r"residual RMS ([\d.]+) um", run.stdout)]
    assert len(printed) == 2, run.stdout
    for quoted, got in zip((residual["dh"], residual["errormap"]), printed):
        assert got == pytest.approx(quoted, rel=0.02, abs=0.06), (quoted, got)
    for model, (rms, worst) in unseen.items():
        m = re.search(rf"^\s*{model}\s+RMS\s+([\d.]+) um\s+max\s+([\d.]+) um", run.stdout, re.M)
        assert m, run.stdout
        assert float(m.group(1)) == pytest.approx(rms, rel=0.03, abs=0.6), model
        assert float(m.group(2)) == pytest.approx(worst, rel=0.03, abs=0.6), model
