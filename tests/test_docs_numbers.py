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


def _machine_3d_quoted():
    """docs/machine_3d.md's walk-through figures: the check's RMS move (µm) and its ratio to u, the inflation,
    the share within 3 u before and after (%), the max before / after (u)."""
    with open(os.path.join(ROOT, "docs", "machine_3d.md"), encoding="utf-8") as f:
        text = " ".join(f.read().split())
    m = re.search(r"the tool points move by RMS ([\d.]+) µm \(max [\d.]+ µm\), ([\d.]+) × the stated u, and every u "
                  r"is inflated ([\d.]+) ×.*?before the check (\d+) % of the coordinates were within 3 u \(max "
                  r"([\d.]+) u\); with the inflated u (\d+) % \(max ([\d.]+) u\)", text)
    assert m, "docs/machine_3d.md: the sentence with the walk-through's under-resolution figures is gone"
    return [float(g) for g in m.groups()]


def test_the_machine_3d_walk_through_quotes_what_it_prints(tmp_path):
    """The documented walk-through (olti simulate diagrams/machine_3d.yaml, olti identify --model volumetric):
    the under-resolution check's figures in the summary and the coverage of the truth before and after."""
    import json

    import numpy as np

    from olti_drake.io.volumetric_io import load_volumetric_result

    move, ratio, inflation, before, max_before, after, max_after = _machine_3d_quoted()
    olti = [sys.executable, "-m", "olti_drake.cli"]
    run = subprocess.run(olti + ["simulate", "diagrams/machine_3d.yaml", "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    run = subprocess.run(olti + ["identify", str(tmp_path / "campaign.csv"), "--model", "volumetric",
                                 "--tool-offsets-mm", "0,0,100;80,0,100;0,80,140", "--out", str(tmp_path / "vol.json")],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    m = re.search(r"resolution check: the fit on <= 250 mm knots moves the tool points by RMS ([\d.]+) um \(([\d.]+) x "
                  r"the stated u\) -- too coarse: u inflated ([\d.]+) x", run.stdout)
    assert m and "--knot-spacing-mm 250" in run.stdout, run.stdout
    for quoted, got in zip((move, ratio, inflation), map(float, m.groups())):
        assert got == pytest.approx(quoted, rel=0.05), (quoted, got)
    truth = json.loads((tmp_path / "truth.json").read_text())
    res = load_volumetric_result(tmp_path / "vol.json")
    cmd, tool = np.asarray(truth["commands_mm"]), np.asarray(truth["tools"])
    p, _ = res.model.jacobian(cmd, tool, res.params)
    u = res.position_std(cmd, tool)
    seen = u > 1e-9
    z = np.abs(p - np.asarray(truth["targets_mm"]))[seen] / u[seen]
    g = res.doc["resolution_check"]["inflation"]
    assert 100 * np.mean(z * g <= 3) == pytest.approx(before, abs=2)
    assert float(np.max(z * g)) == pytest.approx(max_before, rel=0.05)
    assert 100 * np.mean(z <= 3) == pytest.approx(after, abs=1) and 100 * np.mean(z <= 3) >= 95
    assert float(np.max(z)) == pytest.approx(max_after, rel=0.05)
