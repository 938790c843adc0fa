"""olti report RESULT --iso9283 VALIDATION.csv [--tolerance ...] for a robot from a model file (issue 26, item 4):
ISO 9283 AP and RP per pose from a tracker campaign with repeated cycles; the nominal kinematics' AP shows the
robot's error, the identified model's what a compensation leaves; verdicts against tolerances; the data file's
hash on the page."""

import hashlib

import numpy as np
import pytest

from olti_drake.cli.verbs import main
from olti_drake.io.serial_io import write_serial_campaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.model.frames import into_frame
from olti_drake.model.serial import synthetic_campaign, synthetic_truth


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    import os

    d = tmp_path_factory.mktemp("iso9283")
    chain = load_serial_chain(os.path.join(PACKAGE_DIR, "models", "ur5.urdf"), "tool0")
    truth = synthetic_truth(chain, seed=5, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, 300, seed=5, noise_mm=0.002)
    write_serial_campaign(d / "points.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    assert main(["identify", str(d / "points.csv"), "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm",
                 "40,-25,60", "--model", "errormap", "--out", str(d / "result.json")]) == 0
    poses = synthetic_campaign(truth, 5, seed=77)
    n = 12
    rng = np.random.default_rng(3)
    cmd, dirs = np.tile(poses.commands, (n, 1)), np.tile(poses.dirs, (n, 1))
    base = truth.positions(cmd, dirs) + 0.015 * rng.standard_normal((len(cmd), 3))  # 15 um repeatability
    write_serial_campaign(d / "validation.csv", cmd, dirs, points_mm=into_frame(base, truth.frame))
    return d


def test_the_report_states_ap_and_rp_per_pose_with_verdicts(case, capsys):
    d = case
    assert main(["report", str(d / "result.json"), "--iso9283", str(d / "validation.csv"), "--tolerance",
                 "AP_P=0.1,RP_l=0.1", "--out", str(d / "rep")]) == 0
    html = (d / "rep" / "report.html").read_text()
    assert "ISO 9283 pose accuracy and repeatability" in html
    assert hashlib.sha256((d / "validation.csv").read_bytes()).hexdigest()[:16] in html
    import re

    section = html[html.index("ISO 9283 pose accuracy"):]
    rows = [re.findall(r"<td[^>]*>([^<]*)</td>", r) for r in section.split("<tr>")]
    rows = [r for r in rows if r and re.fullmatch(r"P\d", r[0])]
    assert len(rows) == 5
    nominal, identified, rp = (np.array([float(r[k]) for r in rows]) for k in (2, 3, 4))
    assert np.all(nominal > 5 * identified), (nominal, identified)  # the uncalibrated robot vs the model
    assert np.all(identified < 40.0) and np.all((rp > 20.0) & (rp < 90.0))  # um; 15 um noise: l-bar + 3 S_l
    assert "nominal: AP_P FAIL" in html and "identified: AP_P PASS" in html and "identified: RP_l PASS" in html


def test_bad_iso9283_inputs_are_one_line(case, capsys):
    d = case
    capsys.readouterr()
    assert main(["report", str(d / "result.json"), "--tolerance", "AP_P=0.1", "--out", str(d / "r2")]) != 0
    assert "--tolerance needs --iso9283" in capsys.readouterr().err
    assert main(["report", str(d / "result.json"), "--iso9283", str(d / "validation.csv"), "--tolerance", "APX=1",
                 "--out", str(d / "r3")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "APX" in err[0]
    with pytest.raises(SystemExit):
        main(["report", str(d / "result.json"), "--iso9283", str(d / "validation.csv"), "--tolerance", "AP_P=-1",
              "--out", str(d / "r4")])
