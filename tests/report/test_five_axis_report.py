"""``olti report`` of a five-axis result (issue 25, item 7): the location errors with U, one figure of error
motions per rotary axis, the residuals per reading kind, the KinematicsOpt-style acceptance summary with verdicts,
the BK check hook and the notes; an uncertainty file of another result refused in one line. A small errormap
identification (maps every 30 deg) of a truth outside the model family."""

import json
import re
from html.parser import HTMLParser

import pytest

from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_truth import synthetic_truth
from tests.estimation.test_five_axis_identify import SIX_TABLE_STATIONS, TRUNNION, distance_campaign, no_dropped_truth
from olti_calls import error_line, olti_in
from tests.estimation.test_five_axis_uncertainty import MACHINE, identified, uncertainty


class Rows(HTMLParser):
    """The text of every table row (a list of cells) and every img alt."""

    def __init__(self):
        super().__init__()
        self.rows, self.alts, self.cell = [], [], None

    def handle_starttag(self, tag, attrs):
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self.cell = ""
        elif tag == "img":
            self.alts.append(dict(attrs).get("alt", ""))

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self.cell is not None:
            self.rows[-1].append(self.cell.strip())
            self.cell = None

    def handle_data(self, data):
        if self.cell is not None:
            self.cell += data


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    machine = FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")
    truth = no_dropped_truth(synthetic_truth(machine, seed=3))
    campaign, result = identified(folder, distance_campaign(machine, truth, 40, 2, SIX_TABLE_STATIONS, "workpiece"),
                                  "--model", "errormap", "--grid-step-deg", "30")
    unc = folder / "unc.json"
    uncertainty(result, campaign, unc, "--method", "linear", "--k", "2")
    out = folder / "page"
    olti_in("report", result, unc, "--campaign", campaign, "--out", out,
            "--tolerance", "dispersion=0.05,modification_mm=0.001,modification_urad=1000", expect=0)
    html = (out / "report.html").read_text()
    parser = Rows()
    parser.feed(html)
    return folder, json.loads(result.read_text()), json.loads(unc.read_text()), html, parser, result, unc, campaign


def test_every_location_error_with_its_value_and_U(case):
    _, doc, unc, _, page, *_ = case
    rows = {r[0]: r for r in page.rows if len(r) == 7 and r[0].startswith("E_")}  # (the location table)
    for name, v in doc["location_errors"].items():
        row = rows[name]
        scale = 1e3 if name.endswith("_mm") else 1.0
        assert row[2] == f"{scale * v:+.3f}", row
        if name in doc["held"]:
            assert row[5] == "—" and row[6].startswith("held at 0: ") and doc["dropped"][name] in row[6], row
        else:
            assert row[5] == f"{2 * scale * unc['location_errors'][name]:.3f}" and row[6] == "identified", row


def test_one_figure_of_error_motions_per_rotary_axis(case):
    folder, doc, *_ = case
    page = case[4]
    for axis in ("A", "C"):
        assert (folder / "page" / f"fig_motions_{axis}.png").stat().st_size > 10_000
        assert any(f"error motions of the {axis} axis, forward and reverse" in a for a in page.alts), page.alts
    motions = {r[0] for r in page.rows if r and re.fullmatch(r"E_[XYZABC][AC]", r[0])}
    assert motions == set(doc["error_motions"]) and len(motions) == 12


def test_residuals_and_acceptance_summary_with_verdicts(case):
    _, doc, _, html, page, *_ = case
    residual = next(r for r in page.rows if r and r[0] == "distances (station)")
    assert int(residual[1]) == doc["n_readings"]
    assert float(residual[2]) == pytest.approx(1e3 * doc["residual_rms_mm"], abs=2e-3)  # (re-solved on the campaign)
    dispersion = next(r for r in page.rows if r and r[0] == "dispersion")
    assert float(dispersion[2].split()[0]) == pytest.approx(float(residual[3]), abs=1e-3)
    free = {n: v for n, v in doc["location_errors"].items() if n not in doc["held"]}
    linear = max((n for n in free if n.endswith("_mm")), key=lambda n: abs(free[n]))
    modification = next(r for r in page.rows if r and r[0] == "maximum modification (linear)")
    assert modification[1].startswith(linear) and modification[2] == f"{1e3 * free[linear]:+.3f} µm"
    verdicts = [r[0] for r in page.rows if r and r[0].startswith(("dispersion ", "maximum modification E_"))]
    assert len(verdicts) == 3, verdicts
    assert "PASS" in verdicts[0] and "exceeds the tolerance" in verdicts[1] and "within tolerance" in verdicts[2]
    assert "BK check paths (ISO 10791-6)" in html and "Notes, gauge and what was held" in html
    for g in doc["dropped"]:
        assert any(r and r[0] == g for r in page.rows), g


def test_uncertainty_file_of_another_result_is_refused_in_one_line(case, capsys):
    folder, doc, _, _, _, result, unc, _ = case
    other = dict(doc, location_errors={**doc["location_errors"], "E_X0C_mm": doc["location_errors"]["E_X0C_mm"] + 1e-3})
    (folder / "other.json").write_text(json.dumps(other))
    code, _, err = olti_in("report", folder / "other.json", unc, "--out", folder / "refused")
    error_line(code, err, "another result")
    assert not (folder / "refused" / "report.html").exists()
    code, _, err = olti_in("report", result, "--tolerance", "AP_P=0.1", "--out", folder / "refused")
    error_line(code, err, "dispersion", "modification_mm")


def test_bk_check_paths_before_and_after_compensation_or_not_computed(case, monkeypatch, tmp_path):
    """The hook to model.five_axis_compensation.bk_check: a geometric result of the same campaign (the compensation
    inverts it exactly) gives BK paths whose deviation before compensation is the location errors' (tens of µm),
    after it what the inverse leaves (< 0.01 µm), with U > 0; without the function the section says 'not
    computed'."""
    from olti_drake.io.five_axis_io import load_machine5_result
    from olti_drake.model import five_axis_compensation
    from olti_drake.report import page as ui
    from olti_drake.report.five_axis_report import _bk_section

    folder, *_, campaign = case
    olti_in("identify", campaign, *MACHINE, "--model", "geometric", "--out", folder / "geometric.json", expect=0)
    res = load_machine5_result(folder / "geometric.json")
    page = ui.Page(tmp_path)
    check = _bk_section(page, res, 2.0)
    assert check is not None and check.names == ("A alone", "C alone", "A+C"), page.parts
    assert min(check.nominal_max_um) > 10.0 and max(check.compensated_max_um) < 0.01, check.describe()
    rows = Rows()
    rows.feed("".join(page.parts))
    table = [r for r in rows.rows if r and r[0] in check.names]
    assert len(table) == 3 and all(float(r[-1]) > 0 for r in table), table
    monkeypatch.delattr(five_axis_compensation, "bk_check")
    page = ui.Page(tmp_path)
    assert _bk_section(page, res, 2.0) is None and "not computed" in "".join(page.parts)
