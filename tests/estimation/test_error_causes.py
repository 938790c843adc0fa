"""Errors and warnings that name the real cause (issue 24, class 7), through the CLI.

A single 5 mm blunder in an l2 fit is named first with its line and the Huber loss, and the under-resolution
check says it is not conclusive; an empty path names its argument; a campaign given as a plan is refused as
one; readings in metres or with their sign flipped are said to be so, never numpy's bare "Singular matrix".
"""

from pathlib import Path

import pytest
from olti_calls import error_line, olti_sub

ROOT = Path(__file__).resolve().parents[2]
CAMPAIGN = ROOT / "data" / "paper000" / "campaign.csv"
REGIONS = ROOT / "data" / "regions_paper000.yaml"
MACHINE = ROOT / "diagrams" / "machine_3d.yaml"


def one_error_line(p) -> str:
    return error_line(p.returncode, p.stderr)


def _changed(src: Path, dst: Path, change, file_line=None) -> Path:
    """A copy of the campaign ``src`` with ``change(value)`` applied to displacement_mm (at one 1-based file
    line only, when ``file_line`` is given)."""
    out, header = [], None
    for no, line in enumerate(src.read_text().splitlines(), 1):
        if line.startswith("#") or not line.strip():
            out.append(line)
            continue
        parts = line.split(",")
        if header is None:
            header = parts
            out.append(line)
            continue
        if file_line is None or no == file_line:
            i = header.index("displacement_mm")
            parts[i] = f"{change(float(parts[i])):.12g}"
        out.append(",".join(parts))
    dst.write_text("\n".join(out) + "\n")
    return dst


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    out = tmp_path_factory.mktemp("machine")
    p = olti_sub("simulate", MACHINE, "--out", out)
    assert p.returncode == 0, p.stderr
    return out / "campaign.csv"


def test_blunder_is_named_first_with_its_line_and_the_huber_loss(tmp_path):
    bad = _changed(CAMPAIGN, tmp_path / "blunder.csv", lambda v: v + 5.0, file_line=104)
    p = olti_sub("identify", bad, "--model", "errormap", "--out", tmp_path / "r.json")
    assert p.returncode == 0, p.stderr
    warnings = [x.strip() for x in p.stdout.splitlines() if x.strip().startswith("warning:")]
    assert warnings and "gross outlier" in warnings[0] and "line 104" in warnings[0], p.stdout
    assert "--loss huber" in warnings[0] and "sigma" in warnings[0], warnings[0]
    # The under-resolution check is qualified: a blunder, not the node spacing, makes its miss.
    resolution = [w for w in warnings if "under-resolution" in w]
    assert resolution and all("not conclusive" in w and "line 104" in w for w in resolution), warnings
    assert not any(w.endswith("(finer plan)") for w in warnings), warnings
    # The Huber loss down-weights it: no gross-outlier warning then.
    h = olti_sub("identify", bad, "--model", "errormap", "--loss", "huber", "--out", tmp_path / "h.json")
    assert h.returncode == 0 and "gross outlier" not in h.stdout, h.stdout


def test_clean_campaign_has_no_gross_outlier_warning(tmp_path):
    p = olti_sub("identify", CAMPAIGN, "--model", "errormap", "--out", tmp_path / "r.json")
    assert p.returncode == 0 and "gross outlier" not in p.stdout and "not conclusive" not in p.stdout, p.stdout


def test_empty_paths_name_the_argument(tmp_path):
    msg = one_error_line(olti_sub("identify", "", "--model", "dh", "--out", tmp_path / "r.json"))
    assert "the campaign path is empty" in msg, msg
    msg = one_error_line(olti_sub("identify", CAMPAIGN, "--model", "dh", "--out", ""))
    assert "--out is empty" in msg, msg
    assert not (tmp_path / "r.json").exists()


def test_empty_path_in_the_reader():
    from olti_drake.errors import InputError
    from olti_drake.io.csvio import read_text

    with pytest.raises(InputError, match="the campaign path is empty"):
        read_text("", "campaign")


def test_design_refuses_a_campaign_as_plan(tmp_path):
    result = tmp_path / "r.json"
    assert olti_sub("identify", CAMPAIGN, "--model", "dh", "--out", result).returncode == 0
    msg = one_error_line(olti_sub("design", result, "--plan", CAMPAIGN, "--regions", REGIONS,
                                  "--out", tmp_path / "d.json"))
    assert "a campaign" in msg and "displacement_mm" in msg and "not a plan" in msg, msg
    assert not (tmp_path / "d.json").exists()


def test_machine_readings_in_metres_are_said_to_be(machine, tmp_path):
    metres = _changed(machine, tmp_path / "metres.csv", lambda v: v / 1000)
    for verb in (("multilaterate",), ("identify", "--model", "volumetric")):
        msg = one_error_line(olti_sub(*verb, metres, "--out", tmp_path / "r.json"))
        assert "another unit (metres?)" in msg, msg
        assert "station layout" not in msg and "Singular matrix" not in msg, msg


def test_machine_readings_with_flipped_sign_are_not_blamed_on_the_layout(machine, tmp_path):
    flipped = _changed(machine, tmp_path / "flipped.csv", lambda v: -v)
    msg = one_error_line(olti_sub("multilaterate", flipped, "--out", tmp_path / "r.json"))
    assert "sign is flipped" in msg and "Singular matrix" not in msg and "lie on one" not in msg, msg


def test_station_fit_failure_names_the_readings():
    import numpy as np

    from olti_drake.estimation.calibration import StationFitFailed, station_fit

    rng = np.random.default_rng(0)
    p = rng.uniform(0, 400, (30, 3))
    d = np.linalg.norm(p - [900.0, 100.0, 50.0], axis=1) - 800.0
    with pytest.raises(StationFitFailed, match="another unit"):
        station_fit(p, d / 1000)


def test_scara_readings_with_flipped_sign_are_said_to_be(tmp_path):
    flipped = _changed(CAMPAIGN, tmp_path / "flipped.csv", lambda v: -v)
    for model in ("dh", "errormap"):
        msg = one_error_line(olti_sub("identify", flipped, "--model", model, "--out", tmp_path / "r.json"))
        assert "sign flipped" in msg and "reflector layout" not in msg and "not identifiable" not in msg, msg


def test_wrong_fixed_reflectors_are_named_first(tmp_path):
    p = olti_sub("identify", CAMPAIGN, "--model", "errormap", "--reflectors-mm", "600,-400;700,0;600,400",
                 "--fix-reflectors", "--out", tmp_path / "r.json")
    assert p.returncode == 0, p.stderr
    warnings = [x.strip() for x in p.stdout.splitlines() if x.strip().startswith("warning:")]
    assert warnings and "fixed reflectors" in warnings[0] and "--reflectors-mm" in warnings[0], warnings
    assert not any(w.endswith("(finer plan)") for w in warnings), warnings


def test_volumetric_tool_offsets_in_metres_are_blamed_not_the_motions(machine, tmp_path):
    msg = one_error_line(olti_sub("identify", machine, "--model", "volumetric", "--tool-offsets-mm",
                                  "0,0,0;0.08,0,0;0,0.08,0.04", "--out", tmp_path / "r.json"))
    head = msg.split("physically impossible")[0]
    assert "--tool-offsets-mm" in head and "in metres?" in head and "leave --tool-offsets-mm out" in head, msg
