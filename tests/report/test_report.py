"""The calibration report (`olti report`) and the ISO 230-2 style statistics (olti_drake.report.iso230).

One module-scoped fixture identifies the error-map model on the shipped paper campaign
(data/paper000/campaign.csv, the simulated paper-000 experiment), propagates the 000 Table 2 budget
linearly (`olti uncertainty`) and writes the full report with campaign and truth. Units: mm and degrees.
"""

import base64
import json
import os
import re
import shutil
import types

import numpy as np
import pytest
from figure_capture import annotations, captured_figures, errorbar, legend_labels, line, suptitle

from olti_drake.io.csvio import load_campaign
from olti_drake.cli import main
from olti_drake.model.errormap import ErrorMap
from olti_drake.estimation.identification import IdentificationOptions, identify, parse_grid
from olti_drake.report.iso230 import STATISTICS, axis_statistics, map_statistics
from olti_drake.report.html import write_report
from olti_drake.io.result import load_result, write_result
from olti_drake.sim.scenario import Robot
from olti_calls import error_line, olti_in

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")
TRUTH = os.path.join(ROOT, "data", "paper000", "truth.json")
PNG = b"\x89PNG\r\n\x1a\n"
FULL_FIGURES = {"fig_maps.png", "fig_reversal.png", "fig_uncertainty_map.png", "fig_residuals.png",
                "fig_path_x200.png", "fig_error_vectors.png"}


@pytest.fixture(scope="module")
def paper_figures():
    """{file name: matplotlib Figure} of the full paper report, filled by ``paper``."""
    return {}


@pytest.fixture(scope="module")
def paper(tmp_path_factory, paper_figures):
    """result.json (error map), unc.json (linear, 000 Table 2) and the full report of the paper campaign."""
    d = tmp_path_factory.mktemp("report")
    data = load_campaign(CAMPAIGN)
    write_result(identify(data, IdentificationOptions(model="errormap")), d / "result.json")
    assert main(["uncertainty", str(d / "result.json"), CAMPAIGN, "--method", "linear",
                 "--out", str(d / "unc.json")]) == 0
    with captured_figures() as figs:
        written = write_report(d / "result.json", d / "out", d / "unc.json", CAMPAIGN, TRUTH)
    paper_figures.update(figs)
    return d, written


def _html(path):
    """The page without its data-sha256 stamps (every number's data file: tests/report/test_report_hashes.py)."""
    with open(path, encoding="utf-8") as f:
        return re.sub(r' data-sha256="[0-9a-f]*"', "", f.read())


def _imgs(html_text):
    return re.findall(r"<img\b[^>]*\bsrc=\"([^\"]*)\"", html_text)


def assert_self_contained(html_path, written):
    """Every <img> is a data: URI holding exactly a written PNG; nothing refers to the network."""
    text = _html(html_path)
    srcs = _imgs(text)
    pngs = [p for p in written if p.endswith(".png")]
    assert len(srcs) == len(pngs) == text.count("<img")
    for src, path in zip(srcs, pngs):
        assert src.startswith("data:image/png;base64,"), src[:40]
        with open(path, "rb") as f:
            assert base64.b64decode(src.split(",", 1)[1]) == f.read()
    assert not re.search(r"https?://", text), "the page refers to the network"
    assert not re.search(r"<(script|link|iframe|object|embed)\b", text, re.I)
    assert not re.search(r"url\(", text), "CSS must not load anything"


def assert_png_files(written):
    for p in written:
        if p.endswith(".png"):
            assert os.path.getsize(p) > 1000, p
            with open(p, "rb") as f:
                assert f.read(8) == PNG, p


# -- the page -----------------------------------------------------------------------------------------
def test_full_report_renders_self_contained_with_every_figure(paper):
    d, written = paper
    names = {os.path.basename(p) for p in written}
    assert FULL_FIGURES <= names and {"report.html", "iso230.json"} <= names
    assert all(os.path.dirname(p) == str(d / "out") for p in written)
    assert_png_files(written)
    html_path = str(d / "out" / "report.html")
    assert_self_contained(html_path, written)
    text = _html(html_path)
    # Header, parameters with u and U (k from the uncertainty file's 'expanded'), ISO table, map method.
    res = json.load(open(d / "result.json"))
    unc = json.load(open(d / "unc.json"))
    assert f"{1e3 * res['residual_rms_mm']:.2f} µm" in text and str(res["n_readings"]) in text
    assert f"{res['L1_mm']:.4f} mm" in text
    assert f"{1e3 * unc['L1_mm']:.2f}</td><td>{2e3 * unc['L1_mm']:.2f}" in text
    assert "U (k = 2)" in text and "reversal value of the axis" in text and "not available" in text.lower()
    assert "linear propagation (JCGM 100) of the full parameter covariance" in text
    assert "repeatab" in text  # R named as not available, not invented
    assert "<dt>date</dt>" not in text  # no wall-clock date unless passed


def test_report_figures_show_what_the_page_says(paper, paper_figures):
    d, written = paper
    assert set(paper_figures) == FULL_FIGURES
    text = _html(written[-1])
    res = json.load(open(d / "result.json"))
    iso = json.load(open(d / "out" / "iso230.json"))["axes"]
    # Fig. 11: the models' panels are predicted deviations, not accuracies; d) is the accuracy.
    titles = [ax.get_title() for ax in paper_figures["fig_error_vectors.png"].axes]
    assert [t.split("\n")[1].split(":")[0] for t in titles] == [
        "RMS of the measured error", "RMS of the predicted deviation (not an accuracy)",
        "RMS of the predicted deviation (not an accuracy)", "RMS of the model's prediction error"]
    # Residuals: one series per reflector j (P0..P2), with the RMS the table prints.
    labels = legend_labels(paper_figures["fig_residuals.png"].axes[0])
    assert [lab.split(":")[0] for lab in labels] == ["reflector 0", "reflector 1", "reflector 2"]
    for j, lab in enumerate(labels):
        rms = lab.split("RMS ")[1].split(" µm")[0]
        assert re.search(rf"<tr><td class=\"l\">reflector {j}</td><td>\d+</td><td>{rms}</td>", text), (lab, j)
    # The uncertainty map marks the result's reflectors as P0..P2, where the result puts them.
    for ax in paper_figures["fig_uncertainty_map.png"].axes[:2]:
        marks = annotations(ax)
        assert sorted(marks) == ["P0", "P1", "P2"]
        for j, q in enumerate(res["reflectors_mm"]):
            assert marks[f"P{j}"] == pytest.approx(tuple(q))
    # Reversal values: the identified B_i and B̄ of iso230.json, and the truth's.
    for ax, axis in zip(paper_figures["fig_reversal.png"].axes, ("J1", "J2")):
        b_mean = 1e3 * iso[axis]["B_mean_deg"]
        assert f"B̄ = {b_mean:.2f} mdeg" in legend_labels(ax) and "truth B_i" in legend_labels(ax)
        _, y, half = errorbar(ax, "B_i = x̄↑_i − x̄↓_i, identified, U (k = 2)")
        np.testing.assert_allclose(y, 1e3 * np.array(iso[axis]["nodes"]["reversal_deg"]))
        np.testing.assert_allclose(half, 2e3 * np.array(iso[axis]["nodes"]["u_reversal_deg"]))
    # Maps: identified values of the result, truth overlaid.
    maps = paper_figures["fig_maps.png"].axes
    for ax, axis in zip(maps, ("J1", "J2")):
        label = [lab for lab in legend_labels(ax) if lab.startswith("identified, positive")][0]
        np.testing.assert_allclose(errorbar(ax, label)[1], 1e3 * np.array(res["error_map"][axis]["forward_deg"]))
        assert any(lab.startswith("truth, positive") for lab in legend_labels(ax))
    assert "Fig. 9" in paper_figures["fig_path_x200.png"].axes[0].get_title()


def test_report_is_deterministic_escapes_text_and_prints_a_given_date(paper, tmp_path):
    d, _ = paper
    res = json.load(open(d / "result.json"))
    res["gauge"] = "<script>alert('x')</script> & <b>bold</b>"
    bad = tmp_path / "result_markup.json"
    bad.write_text(json.dumps(res))
    a = write_report(bad, tmp_path / "a", d / "unc.json", date="2024-06-01")
    b = write_report(bad, tmp_path / "b", d / "unc.json", date="2024-06-01")
    ha, hb = _html(a[-1]), _html(b[-1])
    assert ha == hb  # same input, same bytes
    for pa, pb in zip(a, b):
        with open(pa, "rb") as fa, open(pb, "rb") as fb:
            assert fa.read() == fb.read(), pa
    assert "<script>" not in ha and "<b>bold" not in ha
    assert "&lt;script&gt;alert(&#x27;x&#x27;)&lt;/script&gt; &amp; &lt;b&gt;bold&lt;/b&gt;" in ha
    assert "<dt>date</dt><dd>2024-06-01</dd>" in ha
    # Without the campaign: no covariance, so no map (said so) and independence stated for the ISO u.
    assert "needs the covariance" in ha and "independence is assumed" in ha
    assert_self_contained(a[-1], a)


# -- ISO 230-2 statistics --------------------------------------------------------------------------------
def test_iso230_statistics_of_a_hand_built_map():
    # forward x̄↑ = [1, 3, 2, 6], reverse x̄↓ = [0, 4, -1, 5] mdeg at 0, 10, 20, 30 deg
    f, r = np.array([1.0, 3.0, 2.0, 6.0]), np.array([0.0, 4.0, -1.0, 5.0])
    m = ErrorMap([0, 10, 20, 30], 1e-3 * f, 1e-3 * r, axis="J1")
    s = axis_statistics(m)
    # B_i = [1, -1, 3, 1]; x̄_i = [0.5, 3.5, 0.5, 5.5]
    assert 1e3 * s.reversal_deg == pytest.approx([1, -1, 3, 1])
    assert 1e3 * s.mean_deg == pytest.approx([0.5, 3.5, 0.5, 5.5])
    assert 1e3 * s.B_deg == pytest.approx(3.0) and s.B_index == 2
    assert 1e3 * s.B_mean_deg == pytest.approx(1.0)
    assert 1e3 * s.E_forward_deg == pytest.approx(6 - 1)
    assert 1e3 * s.E_reverse_deg == pytest.approx(5 - (-1))
    assert 1e3 * s.E_deg == pytest.approx(6 - (-1))
    assert 1e3 * s.M_deg == pytest.approx(5.5 - 0.5)
    assert s.where["E"] == ((3, 1), (2, -1)) and s.where["M"] == (3, 0)
    # The sign of B is kept: reverse above forward gives a negative reversal value.
    neg = axis_statistics(ErrorMap([0, 10], [0.0, 0.0], [0.004, 0.002]))
    assert 1e3 * neg.B_deg == pytest.approx(-4.0) and 1e3 * neg.B_mean_deg == pytest.approx(-3.0)
    # Differences do not see the J1 gauge constant.
    shifted = axis_statistics(ErrorMap([0, 10, 20, 30], 1e-3 * (f + 7), 1e-3 * (r + 7)))
    for name in STATISTICS:
        assert shifted.value(name) == pytest.approx(s.value(name), abs=1e-15)


def test_iso230_uncertainty_propagation_independent_and_correlated():
    f, r = np.array([1.0, 3.0, 2.0, 6.0]), np.array([0.0, 4.0, -1.0, 5.0])
    m = ErrorMap([0, 10, 20, 30], 1e-3 * f, 1e-3 * r)
    uf, ur = 1e-3 * np.array([0.1, 0.2, 0.3, 0.4]), 1e-3 * np.array([0.5, 0.6, 0.7, 0.8])
    s = axis_statistics(m, std=(uf, ur))
    assert s.correlated is False
    assert s.u_reversal_deg == pytest.approx(np.hypot(uf, ur))
    assert s.u_mean_deg == pytest.approx(0.5 * np.hypot(uf, ur))
    assert s.u["B"] == pytest.approx(np.hypot(uf[2], ur[2]))  # the arg-max node
    assert s.u["B_mean"] == pytest.approx(np.sqrt(np.sum(uf ** 2 + ur ** 2)) / 4)
    assert s.u["E_forward"] == pytest.approx(np.hypot(uf[3], uf[0]))
    assert s.u["E"] == pytest.approx(np.hypot(uf[3], ur[2]))
    assert s.u["M"] == pytest.approx(0.5 * np.sqrt(uf[3] ** 2 + ur[3] ** 2 + uf[0] ** 2 + ur[0] ** 2))
    # Correlation rho between x̄↑_i and x̄↓_i: u(B_i)² = u↑² + u↓² − 2 rho u↑ u↓, u(x̄_i)² = (... + 2 rho ...)/4.
    rho = 0.8
    C = np.diag(np.concatenate([uf, ur]) ** 2)
    C[np.arange(4), 4 + np.arange(4)] = C[4 + np.arange(4), np.arange(4)] = rho * uf * ur
    c = axis_statistics(m, cov=C)
    assert c.correlated is True
    assert c.u_reversal_deg == pytest.approx(np.sqrt(uf ** 2 + ur ** 2 - 2 * rho * uf * ur))
    assert c.u_mean_deg == pytest.approx(0.5 * np.sqrt(uf ** 2 + ur ** 2 + 2 * rho * uf * ur))
    assert c.u["B_mean"] == pytest.approx(np.sqrt(np.sum(uf ** 2 + ur ** 2 - 2 * rho * uf * ur)) / 4)
    # The runner-up of B (|B_i| = 3 vs 1) is far beyond 2u: not ambiguous; a near tie is.
    assert c.ambiguous["B"] is False
    tie = axis_statistics(ErrorMap([0, 10], [0.0, 0.0], [-0.0030, -0.00299]), std=np.full(4, 1e-4))
    assert tie.ambiguous["B"] is True
    with pytest.raises(ValueError, match="8 values"):
        axis_statistics(m, std=np.ones(3))


def test_iso230_of_the_identified_paper_map_matches_the_truth_within_uncertainty(paper):
    d, _ = paper
    iso = json.load(open(d / "out" / "iso230.json"))["axes"]
    truth = json.load(open(TRUTH))
    robot = Robot()  # the paper truth (scenario defaults): backlash b + b'·θ* on J1, b on J2
    for axis, dev in (("J1", robot.J1), ("J2", robot.J2)):
        t = axis_statistics(ErrorMap.from_dict(truth["error_map"][axis], axis))
        g = t.positions_deg
        b_true = 1e-3 * (dev.backlash_mdeg + dev.backlash_slope_mdeg_per_deg * g)  # forward − reverse, deg
        assert t.reversal_deg == pytest.approx(b_true, abs=1e-12)
        a = iso[axis]
        assert a["nodes"]["positions_deg"] == pytest.approx(g)
        assert a["correlated"] is True  # the campaign gave the node correlations
        for name in ("B", "B_mean", "E", "M"):
            est, u = a[f"{name}_deg"], a["u_deg"][name]
            assert 0 < u < 3e-3, (axis, name, u)  # a few mdeg at most: a real uncertainty, not a placeholder
            assert abs(est - t.value(name)) < 3 * u, (axis, name, est, t.value(name), u)
        # The identified backlash is the truth's: B̄ within 3u and B of the same sign and size.
        assert a["B_mean_deg"] == pytest.approx(np.mean(b_true), abs=3 * a["u_deg"]["B_mean"])
        assert np.sign(a["B_deg"]) == np.sign(t.B_deg)
        # Correlations matter: forward and reverse move together, so u(B̄) is below the independent value.
        u_ind = np.sqrt(np.sum(np.square(a["nodes"]["u_forward_deg"]) + np.square(a["nodes"]["u_reverse_deg"])))
        assert a["u_deg"]["B_mean"] < 0.8 * u_ind / len(g)


def test_map_statistics_of_a_result_and_refusal_of_a_dh_model(paper):
    d, _ = paper
    model = load_result(d / "result.json")[0]
    stats = map_statistics(model)
    assert set(stats) == {"J1", "J2"} and not stats["J1"].u
    assert stats["J2"].forward_deg == pytest.approx(model.map2.forward_deg)
    with pytest.raises(ValueError, match="error-map"):
        map_statistics(types.SimpleNamespace(is_errormap=False))


# -- command line: bad input -------------------------------------------------------------------------------
def _one_line_error(capsys, argv, *needles):
    error_line(*olti_in(*argv, capsys=capsys)[::2], *needles)


def test_cli_bad_input_is_one_line_and_writes_nothing(paper, tmp_path, capsys):
    d, _ = paper
    # An uncertainty file of another result: the same model on a coarser J1 grid (6 nodes, not 11).
    data = load_campaign(CAMPAIGN)
    coarse = identify(data, IdentificationOptions(model="errormap", grid1_deg=parse_grid("-140:60:40", "g")))
    write_result(coarse, tmp_path / "coarse.json")
    out = tmp_path / "out"
    _one_line_error(capsys, ["report", str(tmp_path / "coarse.json"), str(d / "unc.json"), "--out", str(out)],
                    "does not match", "error_map.J1.forward_deg")
    dh = identify(data, IdentificationOptions(model="dh"))
    write_result(dh, tmp_path / "dh.json")
    _one_line_error(capsys, ["report", str(tmp_path / "dh.json"), str(d / "unc.json"), "--out", str(out)],
                    "does not match", "theta20_deg")
    _one_line_error(capsys, ["report", str(d / "result.json"), TRUTH, "--out", str(out)],
                    "'format' must be 'olti-uncertainty/1'")
    _one_line_error(capsys, ["report", str(d / "unc.json"), "--out", str(out)], "'format' must be")
    _one_line_error(capsys, ["report", str(tmp_path / "missing.json"), "--out", str(out)], "missing.json")
    _one_line_error(capsys, ["report", str(d / "result.json"), "--out", str(out), "--campaign",
                             str(tmp_path / "nope.csv")], "nope.csv")
    # A result given as the truth: same format, but an estimate -- refused, naming the file.
    _one_line_error(capsys, ["report", str(d / "result.json"), "--out", str(out), "--campaign", CAMPAIGN,
                             "--truth", str(tmp_path / "dh.json")], "dh.json", "not a simulation truth")
    assert not out.exists()
    # Never overwrite an input: a result called report.html in the output directory.
    shutil.copy(d / "result.json", tmp_path / "report.html")
    before = (tmp_path / "report.html").read_bytes()
    _one_line_error(capsys, ["report", str(tmp_path / "report.html"), "--out", str(tmp_path)],
                    "overwrite an input")
    assert (tmp_path / "report.html").read_bytes() == before
    assert not (tmp_path / "fig_maps.png").exists()


def test_cli_dh_report_with_campaign_and_truth(paper, tmp_path, capsys):
    d, _ = paper
    write_result(identify(load_campaign(CAMPAIGN), IdentificationOptions(model="dh")), tmp_path / "dh.json")
    assert main(["report", str(tmp_path / "dh.json"), "--out", str(tmp_path / "r"), "--campaign", CAMPAIGN,
                 "--truth", TRUTH]) == 0
    printed = capsys.readouterr().out
    written = [l[len("wrote "):] for l in printed.splitlines() if l.startswith("wrote ")]
    names = {os.path.basename(p) for p in written}
    assert names == {"fig_residuals.png", "fig_path_x200.png", "fig_error_vectors.png", "report.html"}
    assert_png_files(written)
    assert_self_contained(written[-1], written)
    text = _html(written[-1])
    assert "θ20" in text and "ISO 230-2 style" not in text  # no map, no ISO table
    # The validation table: the error map (identified from the campaign) beats the D-H model (000 §4.3).
    rms = re.findall(r"<td class=\"l\">grid paths</td><td class=\"l\">(D-H|error map)</td><td>\d+</td>"
                     r"<td>([\d.]+)</td>", text)
    got = {m: float(v) for m, v in rms}
    assert set(got) == {"D-H", "error map"} and got["error map"] < 0.5 * got["D-H"]


# -- machine tool (001) ------------------------------------------------------------------------------------
def test_multilateration_report_renders_targets_and_uncertainties(paper, tmp_path, capsys):
    from olti_drake.io.csvio import write_machine_campaign
    from olti_drake.model.machine import MachineScenario, simulate_machine_campaign

    cols, _ = simulate_machine_campaign(MachineScenario())
    write_machine_campaign(cols, tmp_path / "m.csv")
    assert main(["multilaterate", str(tmp_path / "m.csv"), "--out", str(tmp_path / "ml.json")]) == 0
    assert main(["uncertainty", str(tmp_path / "ml.json"), str(tmp_path / "m.csv"), "--method", "linear",
                 "--out", str(tmp_path / "mu.json")]) == 0
    capsys.readouterr()
    with captured_figures() as figs:
        written = write_report(tmp_path / "ml.json", tmp_path / "r", tmp_path / "mu.json", tmp_path / "m.csv")
    # Fig. 10 of a result: the identified stations, and no digital-scale comparison claimed (none is drawn).
    fig10 = figs["fig_targets.png"]
    stations = np.array(json.load(open(tmp_path / "ml.json"))["stations_mm"])
    np.testing.assert_allclose(line(fig10.axes[0], "stations (identified)"), stations)
    assert "digital scale" not in suptitle(fig10) + " ".join(legend_labels(fig10.axes[1]))
    assert not any("true" in lab for ax in fig10.axes for lab in legend_labels(ax))
    names = {os.path.basename(p) for p in written}
    assert names == {"fig_targets.png", "fig_target_uncertainty.png", "fig_residuals.png", "report.html"}
    assert_png_files(written)
    assert_self_contained(written[-1], written)
    text = _html(written[-1])
    res, unc = json.load(open(tmp_path / "ml.json")), json.load(open(tmp_path / "mu.json"))
    T, c, u = np.array(res["targets_mm"]), np.array(res["commands_mm"]), np.array(unc["targets_mm"])
    dev = 1e3 * np.hypot(*(T - c).T)
    U = 2e3 * np.hypot(*u.T)
    assert f"Deviation from the commands: max {dev.max():.2f} µm, mean {dev.mean():.2f} µm" in text
    assert f"max {U.max():.2f} µm" in text
    assert text.count("<tr>") >= len(T) + len(res["stations_mm"]) + 2  # every target and station has a row
    assert "ISO 230-2 statistics are given for the SCARA error map only" in text
    # An uncertainty file of a SCARA result does not fit; --truth is for SCARA only.
    _one_line_error(capsys, ["report", str(tmp_path / "ml.json"), str(paper[0] / "unc.json"), "--out",
                             str(tmp_path / "x")], "does not match", "targets_mm")
    _one_line_error(capsys, ["report", str(tmp_path / "ml.json"), "--out", str(tmp_path / "x"), "--truth", TRUTH],
                    "SCARA")
