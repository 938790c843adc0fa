"""Docs that quote numbers keep them (issue 24, class 9): the figures `docs/six_axis_campaign.md` quotes for the
shipped six-axis scenario are the ones `olti demo --robot six_axis` prints (read from the doc's sentence, so an
edit of either side that lets them drift fails here), and docs/machine_3d.md's walk-through (its block of commands
run as the doc writes them) prints and writes the figures the doc quotes. The tutorial's quoted outputs have their
own test (tests/package/test_tutorial.py); every doc's other commands are run or parsed in tests/package/test_docs_commands.py."""

import os
import re

import pytest
from olti_calls import olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


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
    run = olti_sub("demo", "--robot", "six_axis", "--out", tmp_path / "demo", timeout=600, expect=0)
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


def _machine_3d_finer_quoted():
    """docs/machine_3d.md's figures of the walk-through with --knot-spacing-mm 250 and of the campaign: the
    readings and targets, the residual RMS by default and with 250 mm knots (µm), the share within 3 u then (%)
    and its max (u)."""
    with open(os.path.join(ROOT, "docs", "machine_3d.md"), encoding="utf-8") as f:
        text = " ".join(f.read().split())
    m = re.search(r"On the shipped scenario \((\d+) readings of (\d+) targets\) the default knots are (\d+) mm -- "
                  r"one cubic per axis on the 6 × 5 × 4 grid.*?the tool points move by RMS [\d.]+ µm \(max ([\d.]+) µm\)",
                  text)
    f = re.search(r"With `--knot-spacing-mm 250` the residual RMS falls from ([\d.]+) to ([\d.]+) µm and (\d+) % "
                  r"are within 3 u of the uninflated u \(max ([\d.]+) u\); on this grid no finer spline is identifiable, "
                  r"so that fit's summary says `resolution check not possible`", text)
    assert m and f, "docs/machine_3d.md: the walk-through's counts or its --knot-spacing-mm 250 figures are gone"
    return [float(g) for g in m.groups()], [float(g) for g in f.groups()]


def _coverage(truth, path):
    """(z, inflation): |identified - true tool point| / u per coordinate (u as stated) of a volumetric result."""
    import numpy as np

    from olti_drake.io.volumetric_io import load_volumetric_result

    res = load_volumetric_result(path)
    cmd, tool = np.asarray(truth["commands_mm"]), np.asarray(truth["tools"])
    p, _ = res.model.jacobian(cmd, tool, res.params)
    u = res.position_std(cmd, tool)
    seen = u > 1e-9
    z = np.abs(p - np.asarray(truth["targets_mm"]))[seen] / u[seen]
    return z, res.doc["resolution_check"].get("inflation", 1.0)


def test_the_machine_3d_walk_through_quotes_what_it_prints(tmp_path):
    """The documented walk-through (olti simulate diagrams/machine_3d.yaml, then the doc's block: olti
    multilaterate and olti identify --model volumetric, and the latter again with --knot-spacing-mm 250):
    the counts, the under-resolution check's figures in the summary, the coverage of the truth before and
    after, and the finer fit's residual and coverage."""
    import json

    import numpy as np

    from tests.package.test_docs_commands import run_block

    move, ratio, inflation, before, max_before, after, max_after = _machine_3d_quoted()
    (n_readings, n_targets, knots, move_max), (rms, rms_250, within_250, max_250) = _machine_3d_finer_quoted()
    run = olti_sub("simulate", "diagrams/machine_3d.yaml", "--out", tmp_path, timeout=600, expect=0)
    counts = rf"{n_readings:.0f} readings \(\d+ valid, \d+ beam lost\) of {n_targets:.0f} targets"
    assert re.search(counts, run.stdout), run.stdout
    out = run_block("docs/machine_3d.md", "olti multilaterate DIR/campaign.csv", ROOT, subst=tmp_path)
    assert len(out) == 2 and (tmp_path / "ml.json").is_file()
    printed = next(v for k, v in out.items() if "volumetric" in k)
    m = re.search(r"resolution check: the fit on <= 250 mm knots moves the tool points by RMS ([\d.]+) um \(([\d.]+) x "
                  r"the stated u\) -- too coarse: u inflated ([\d.]+) x", printed)
    assert m and "--knot-spacing-mm 250" in printed, printed
    for quoted, got in zip((move, ratio, inflation), map(float, m.groups())):
        assert got == pytest.approx(quoted, rel=0.05), (quoted, got)
    doc = json.loads((tmp_path / "vol.json").read_text())
    assert doc["representation"]["knot_spacing_mm"] == knots
    assert 1e3 * doc["resolution_check"]["difference_max_mm"] == pytest.approx(move_max, rel=0.05)
    truth = json.loads((tmp_path / "truth.json").read_text())
    z, g = _coverage(truth, tmp_path / "vol.json")
    assert 100 * np.mean(z * g <= 3) == pytest.approx(before, abs=2)
    assert float(np.max(z * g)) == pytest.approx(max_before, rel=0.05)
    assert 100 * np.mean(z <= 3) == pytest.approx(after, abs=1) and 100 * np.mean(z <= 3) >= 95
    assert float(np.max(z)) == pytest.approx(max_after, rel=0.05)
    # "With --knot-spacing-mm 250": the doc's identify command with that option added
    (tmp_path / "vol.json").rename(tmp_path / "vol_default.json")
    out = run_block("docs/machine_3d.md", "DIR/campaign.csv --model volumetric", ROOT, subst=tmp_path,
                    extra=["--knot-spacing-mm", "250"], only="--model volumetric")
    printed = next(v for k, v in out.items() if "volumetric" in k)
    assert "resolution check not possible" in printed, printed
    for path, quoted in ((tmp_path / "vol_default.json", rms), (tmp_path / "vol.json", rms_250)):
        got = 1e3 * json.loads(path.read_text())["residual_rms_mm"]
        assert got == pytest.approx(quoted, abs=0.011), (path.name, quoted, got)
    z, g = _coverage(truth, tmp_path / "vol.json")
    assert g == 1.0
    assert 100 * np.mean(z <= 3) == pytest.approx(within_250, abs=1)
    assert float(np.max(z)) == pytest.approx(max_250, rel=0.05)
