"""A SCARA campaign without direction columns (formats.md: optional, one-directional; issue 24 class 9).

The shipped paper-000 campaign with ``dir1, dir2`` dropped: the D-H model (000 Eq. 3-5) does not see
directions; the error-map model (Eq. 6-10) identifies one branch per joint (forward only, no backlash), says
so in its notes and writes one-directional maps, which ``olti predict`` applies to commands without
directions -- while a bidirectional result refuses them. Units: mm and degrees.
"""

import json
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.estimation.identification import ONE_DIRECTIONAL_NOTE, IdentificationOptions, identify
from olti_drake.io.csvio import load_campaign, load_commands
from olti_drake.io.result import load_result, write_result
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")


def drop_columns(src, dst, drop=("dir1", "dir2")):
    """Copy a CSV without the columns ``drop`` (comment lines kept)."""
    out, keep = [], None
    for line in open(src, encoding="utf-8").read().splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            out.append(line)
            continue
        fields = line.split(",")
        if keep is None:
            keep = [i for i, c in enumerate(fields) if c.strip() not in drop]
        out.append(",".join(fields[i] for i in keep))
    open(dst, "w", encoding="utf-8").write("\n".join(out) + "\n")


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    d = tmp_path_factory.mktemp("onedir")
    drop_columns(CAMPAIGN, d / "nodir.csv")
    return d, load_campaign(CAMPAIGN), load_campaign(d / "nodir.csv")


@pytest.fixture(scope="module")
def fits(campaigns):
    _, both, one = campaigns
    return {(m, k): identify(data, IdentificationOptions(model=m))
            for m in ("dh", "errormap") for k, data in (("both", both), ("one", one))}


def test_campaign_without_directions_loads_one_directional(campaigns):
    _, both, one = campaigns
    assert one.one_directional and not both.one_directional
    assert len(one) == len(both)
    np.testing.assert_array_equal(one.commands.theta1_deg, both.commands.theta1_deg)


def test_one_direction_column_alone_is_refused(campaigns, tmp_path):
    drop_columns(CAMPAIGN, tmp_path / "half.csv", drop=("dir2",))
    with pytest.raises(InputError, match="missing required column 'dir2'"):
        load_campaign(tmp_path / "half.csv")


def test_dh_does_not_see_directions(fits):
    a, b = fits[("dh", "both")], fits[("dh", "one")]
    for name in ("L1_mm", "L2_mm", "theta20_deg"):
        assert abs(a.value(name) - b.value(name)) <= b.uncertainty(name), name
    assert ONE_DIRECTIONAL_NOTE not in b.notes


def test_errormap_one_branch_near_the_mean_of_both(fits):
    a, b = fits[("errormap", "both")], fits[("errormap", "one")]
    assert not b.model.bidirectional and a.model.bidirectional
    assert ONE_DIRECTIONAL_NOTE in b.notes
    assert not any("reverse" in n for n in b.names)
    for axis, ma, mb in (("J1", a.model.map1, b.model.map1), ("J2", a.model.map2, b.model.map2)):
        mean = (ma.forward_deg + ma.reverse_deg) / 2
        u = np.array([b.uncertainty(f"{axis}_forward_deg[{i}]") for i in range(mb.n_nodes)])
        miss = np.abs(mb.forward_deg - mean)
        assert np.all(miss <= 3 * u + 1e-12), (axis, (miss / np.maximum(u, 1e-300)).max())
    assert "one-directional" in b.gauge


def test_one_directional_result_document(fits, tmp_path):
    write_result(fits[("errormap", "one")], tmp_path / "r.json")
    doc = json.load(open(tmp_path / "r.json"))
    assert doc["bidirectional"] is False
    assert ONE_DIRECTIONAL_NOTE in doc["notes"]
    for axis in ("J1", "J2"):
        assert "forward_deg" in doc["error_map"][axis] and "reverse_deg" not in doc["error_map"][axis]
        assert "reverse_deg" not in doc["uncertainty"]["error_map"][axis]
    model, P, d0, _ = load_result(tmp_path / "r.json")
    assert not model.bidirectional
    np.testing.assert_array_equal(model.parameter_vector(), fits[("errormap", "one")].model.parameter_vector())


def test_bidirectional_result_unchanged_in_format(fits, tmp_path):
    write_result(fits[("errormap", "both")], tmp_path / "r.json")
    doc = json.load(open(tmp_path / "r.json"))
    assert "bidirectional" not in doc
    assert all("reverse_deg" in doc["error_map"][a] for a in ("J1", "J2"))


def test_cli_identify_and_predict_without_directions(campaigns):
    d = campaigns[0]
    r = olti_sub("identify", "nodir.csv", "--model", "errormap", "--out", "one.json", cwd=d)
    assert r.returncode == 0, r.stderr
    r = olti_sub("identify", CAMPAIGN, "--model", "errormap", "--out", "both.json", cwd=d)
    assert r.returncode == 0, r.stderr
    (d / "cmd.csv").write_text("theta1_deg,theta2_deg\n0,20\n-40,60\n")
    r = olti_sub("predict", "one.json", "cmd.csv", "--out", "pred.csv", cwd=d)
    assert r.returncode == 0, r.stderr
    header = [l for l in open(d / "pred.csv").read().splitlines() if not l.startswith("#")][0].split(",")
    assert header == ["theta1_deg", "theta2_deg", "x_mm", "y_mm"]
    cmd, _ = load_commands(d / "cmd.csv")
    model = load_result(d / "one.json")[0]
    rows = np.loadtxt(d / "pred.csv", delimiter=",", comments="#", skiprows=1 + sum(
        l.startswith("#") for l in open(d / "pred.csv").read().splitlines()), ndmin=2)
    np.testing.assert_allclose(rows[:, 2:], model.positions(cmd), atol=1e-6)
    # the bidirectional result needs the directions: refused in one line, by name
    r = olti_sub("predict", "both.json", "cmd.csv", "--out", "pred2.csv", cwd=d)
    error_line(r.returncode, r.stderr)
    assert "dir1" in r.stderr and "bidirectional" in r.stderr
    # a one-directional result also takes commands with directions (ignored)
    (d / "cmd2.csv").write_text("theta1_deg,theta2_deg,dir1,dir2\n0,20,1,-1\n-40,60,-1,1\n")
    r = olti_sub("predict", "one.json", "cmd2.csv", "--out", "pred3.csv", cwd=d)
    assert r.returncode == 0, r.stderr


def test_cli_identify_dh_without_directions(campaigns):
    d = campaigns[0]
    r = olti_sub("identify", "nodir.csv", "--model", "dh", "--out", "dh.json", cwd=d)
    assert r.returncode == 0, r.stderr
    assert "bidirectional" not in json.load(open(d / "dh.json"))


def test_report_of_a_one_directional_result(campaigns):
    d = campaigns[0]
    r = olti_sub("identify", "nodir.csv", "--model", "errormap", "--out", "rep.json", cwd=d)
    assert r.returncode == 0, r.stderr
    r = olti_sub("report", "rep.json", "--campaign", "nodir.csv", "--out", "rep", cwd=d)
    assert r.returncode == 0, r.stderr
    assert (d / "rep" / "report.html").exists()
