"""Every number of the HTML report carries the hash of the data file it came from (olti report; issue 26, item 4):
on a robot's page (result, uncertainty file, campaign, ISO 9283 validation campaign), a SCARA's (result,
uncertainty file, campaign, simulation truth) and on a machine's volumetric page (result, campaign), every element whose own text has a digit carries data-sha256 = the sha256 of one of the
input files; the parameters' u and U columns the uncertainty file's, the residuals the campaign's, the ISO 9283
section the validation campaign's; the legend at the top lists every file with its sha256."""

import base64
import hashlib
import os
from html.parser import HTMLParser

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import write_serial_campaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.frames import into_frame
from olti_drake.model.serial import synthetic_campaign, synthetic_truth

from tests.report.test_volumetric_report import simulate


class Elements(HTMLParser):
    """(tag, attrs, own text, the last h2's text) of every element of the body."""

    VOID = {"img", "br", "meta", "hr", "input", "link"}

    def __init__(self):
        super().__init__()
        self.stack, self.out, self.h2, self.in_head = [], [], "", False

    def handle_starttag(self, tag, attrs):
        if tag == "head":
            self.in_head = True
        item = [tag, dict(attrs), "", self.h2]
        if not self.in_head:
            self.out.append(item)
            if tag == "img":
                item[2] = dict(attrs).get("alt", "")
        if tag not in self.VOID:
            self.stack.append(item)

    def handle_endtag(self, tag):
        if tag == "head":
            self.in_head = False
        while self.stack:
            item = self.stack.pop()
            if item[0] == tag:
                if tag == "h2":  # (a heading belongs to its own section)
                    self.h2 = item[3] = item[2]
                break

    def handle_data(self, data):
        if self.stack:
            self.stack[-1][2] += data


def sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def elements(path):
    p = Elements()
    p.feed(open(path, encoding="utf-8").read())
    return p.out


def assert_every_number_is_stamped(report, inputs):
    digests = {sha(p) for p in inputs}
    numbered = [el for el in elements(report) if any(c.isdigit() for c in el[2])]
    assert len(numbered) > 50
    for tag, attrs, text, section in numbered:
        assert attrs.get("data-sha256") in digests, (tag, text[:80], section)
    return numbered


def sections(numbered) -> dict:
    """{section heading ('' before the first): the hashes its numbers carry}."""
    out = {}
    for tag, attrs, text, section in numbered:
        if not text.startswith("olti_drake report;"):  # (the page's footer, the result's, after the last section)
            out.setdefault(section, set()).add(attrs["data-sha256"])
    return out


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    d = tmp_path_factory.mktemp("hash_robot")
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=7, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, 120, seed=7, noise_mm=0.002)
    write_serial_campaign(d / "points.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    assert main(["identify", str(d / "points.csv"), "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm",
                 "40,-25,60", "--model", "dh", "--out", str(d / "result.json")]) == 0
    assert main(["uncertainty", str(d / "result.json"), str(d / "points.csv"), "--method", "linear", "--out",
                 str(d / "unc.json"), "--workspace-poses", "20"]) == 0
    poses = synthetic_campaign(truth, 3, seed=70)
    cmd, dirs = np.tile(poses.commands, (5, 1)), np.tile(poses.dirs, (5, 1))
    pts = truth.positions(cmd, dirs) + 0.01 * np.random.default_rng(2).standard_normal((len(cmd), 3))
    write_serial_campaign(d / "validation.csv", cmd, dirs, points_mm=into_frame(pts, truth.frame))
    assert main(["report", str(d / "result.json"), str(d / "unc.json"), "--campaign", str(d / "points.csv"),
                 "--iso9283", str(d / "validation.csv"), "--out", str(d / "rep")]) == 0
    return d


def test_every_number_of_a_robot_report_carries_its_files_hash(robot):
    d = robot
    inputs = [d / n for n in ("result.json", "unc.json", "points.csv", "validation.csv")]
    numbered = assert_every_number_is_stamped(d / "rep" / "report.html", inputs)
    by_section = sections(numbered)
    iso = [s for s in by_section if s.startswith("ISO 9283")]
    assert len(iso) == 1 and by_section[iso[0]] == {sha(d / "validation.csv")}
    assert by_section["Residuals"] == {sha(d / "points.csv")}
    assert by_section["Identified parameters"] == {sha(d / "result.json"), sha(d / "unc.json")}
    # the u and U columns of the parameter table are the uncertainty file's, the values the result's
    rows = [el for el in elements(d / "rep" / "report.html") if el[3] == "Identified parameters" and el[0] == "td"]
    assert len(rows) > 50 and len(rows) % 5 == 0
    u = [float(rows[i + 2][2]) for i in range(0, len(rows), 5)]
    assert sum(v > 0 for v in u) > len(u) / 2  # (the file is taken, not dropped; the gauge's fixed values have u 0)
    assert all([c[1]["data-sha256"] for c in rows[i:i + 5]] == [sha(d / n) for n in ("result.json",) * 2 + (
        "unc.json",) * 2 + ("result.json",)] for i in range(0, len(rows), 5))
    text = (d / "rep" / "report.html").read_text()
    for p in inputs:  # the legend at the top: file -> sha256
        assert f"{p}</td><td" in text and text.index(sha(p)) < text.index("<h2")


def test_columns_from_another_file_carry_its_hash(tmp_path):
    """A section's table whose u and U columns are an uncertainty file's (Page.source(..., columns=...)): those
    cells carry that file's hash, the others the section's; the next <h2> returns to the result's."""
    from olti_drake.report import page as ui

    (tmp_path / "r.json").write_text("{}")
    (tmp_path / "u.json").write_text("{ }")
    page = ui.Page(tmp_path, tmp_path / "r.json")
    page.add("<h2>Identified parameters</h2>")
    page.source(None, columns={2: tmp_path / "u.json", 3: tmp_path / "u.json"})
    page.add(ui.table(["parameter", "value", "u (k = 1)", "U (k = 2)"], [("a1", "1.5", "0.1", "0.2")] * 3))
    page.add("<h2>Next</h2>")
    page.add(ui.p("3 more"))
    (tmp_path / "p.html").write_text("".join(page.parts))
    got = [(el[2], el[1].get("data-sha256")) for el in elements(tmp_path / "p.html") if el[0] in ("td", "th", "p")]
    r, u = sha(tmp_path / "r.json"), sha(tmp_path / "u.json")
    assert got[:4] == [("parameter", r), ("value", r), ("u (k = 1)", u), ("U (k = 2)", u)]
    assert got[4:8] == [("a1", r), ("1.5", r), ("0.1", u), ("0.2", u)] and got[-1] == ("3 more", r)
    assert list(page.sources) == [str(tmp_path / "r.json"), str(tmp_path / "u.json")]


def _blank_png(fig, plt, path):
    """The figures' PNG bytes are not this test's subject (their captions are): drawn, closed, not rendered."""
    plt.close(fig)
    with open(path, "wb") as f:
        f.write(base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg=="))
    return path


def test_every_number_of_a_volumetric_report_carries_its_files_hash(tmp_path, monkeypatch):
    monkeypatch.setattr("olti_drake.report.figures._save", _blank_png)
    simulate(tmp_path / "campaign.csv", 1, n=60)
    assert main(["identify", str(tmp_path / "campaign.csv"), "--model", "volumetric", "--tool-offsets-mm", "0,0,100",
                 "--knot-spacing-mm", "200", "--out", str(tmp_path / "result.json")]) == 0
    assert main(["report", str(tmp_path / "result.json"), "--campaign", str(tmp_path / "campaign.csv"), "--out",
                 str(tmp_path / "rep")]) == 0
    numbered = assert_every_number_is_stamped(tmp_path / "rep" / "report.html",
                                              [tmp_path / "result.json", tmp_path / "campaign.csv"])
    by_section = sections(numbered)
    assert by_section["Residuals"] == {sha(tmp_path / "campaign.csv")}
    assert by_section["Error motions (ISO 230-1)"] == {sha(tmp_path / "result.json")}


def test_every_number_of_a_scara_report_carries_its_files_hash(tmp_path, monkeypatch):
    """The paper campaign's SCARA page with an uncertainty file, the campaign and the simulation truth: u and U of
    the parameter table are the uncertainty file's, the residuals the campaign's, the 000 §4.3 validation the
    truth's."""
    from olti_drake.estimation.identification import IdentificationOptions, identify
    from olti_drake.io.csvio import load_campaign
    from olti_drake.io.result import write_result

    root = os.path.dirname(PACKAGE_DIR)
    campaign, truth = (os.path.join(root, "data", "paper000", n) for n in ("campaign.csv", "truth.json"))
    monkeypatch.setattr("olti_drake.report.figures._save", _blank_png)
    write_result(identify(load_campaign(campaign), IdentificationOptions(model="errormap")), tmp_path / "result.json")
    assert main(["uncertainty", str(tmp_path / "result.json"), campaign, "--method", "linear", "--out",
                 str(tmp_path / "unc.json")]) == 0
    assert main(["report", str(tmp_path / "result.json"), str(tmp_path / "unc.json"), "--campaign", campaign,
                 "--truth", truth, "--out", str(tmp_path / "rep")]) == 0
    result, unc = sha(tmp_path / "result.json"), sha(tmp_path / "unc.json")
    numbered = assert_every_number_is_stamped(tmp_path / "rep" / "report.html",
                                              [tmp_path / "result.json", tmp_path / "unc.json", campaign, truth])
    by_section = sections(numbered)
    assert by_section["Residuals"] == {sha(campaign)}
    assert by_section[next(s for s in by_section if s.startswith("Validation"))] == {sha(truth)}
    rows = [el for el in elements(tmp_path / "rep" / "report.html") if el[3] == "Identified parameters"
            and el[0] == "td"]
    assert [r[1]["data-sha256"] for r in rows[:5]] == [result, result, unc, unc, result]
