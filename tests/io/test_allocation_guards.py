"""Issue 24 class 3, memory bombs: every option and scenario field that sizes an array is refused in one line
naming it and the size, before any work (exit 2, nothing written) -- the shared guard
:func:`olti_drake.limits.check_allocation` (2 GiB for one array) and the existing node/candidate limits.

Every command runs in a subprocess under an 8 GB address-space limit and a timeout, so that a regression
ends as a test failure (MemoryError, timeout), never as the OOM killer taking the machine.
"""

import functools
import os
import resource

import pytest

from olti_drake.errors import InputError
from olti_drake.limits import MAX_ARRAY_BYTES, check_allocation
from olti_calls import olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCARA = os.path.join(ROOT, "data", "paper000", "campaign.csv")
REGIONS_2D = os.path.join(ROOT, "data", "regions_paper000.yaml")
TOOLS = "0,0,100;80,0,100;0,80,140"
AS_LIMIT = 8_000_000_000


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))


# The shared subprocess call, under the address-space limit and a 120 s timeout (a call may give its own).
olti = functools.partial(olti_sub, timeout=120, preexec_fn=_limit)


def refused(r, *words):
    """Exit 2 and one stderr line that names every word (the option, the size unit)."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr[-2000:])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("note:")]
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    d = tmp_path_factory.mktemp("machine")
    r = olti("simulate", os.path.join(ROOT, "diagrams", "machine_3d.yaml"), "--out", d / "sim")
    assert r.returncode == 0, r.stderr
    r = olti("identify", d / "sim" / "campaign.csv", "--model", "volumetric", "--tool-offsets-mm", TOOLS,
             "--out", d / "R.json")
    assert r.returncode == 0, r.stderr
    (d / "want.csv").write_text("x_mm,y_mm,z_mm\n100,100,150\n")
    (d / "regions.yaml").write_text("regions:\n  - {x_mm: [-1000, 1000], y_mm: [-1000, 1000], z_mm: [0, 1000]}\n")
    return d


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    d = tmp_path_factory.mktemp("six")
    r = olti("simulate", os.path.join(ROOT, "diagrams", "six_axis.yaml"), "--out", d / "sim")
    assert r.returncode == 0, r.stderr
    r = olti("identify", d / "sim" / "campaign.csv", "--model", "errormap", "--robot", "ur5", "--tool-frame", "tool0",
             "--out", d / "S.json")
    assert r.returncode == 0, r.stderr
    (d / "regions.yaml").write_text("regions:\n  - {x_mm: [-1000, 1000], y_mm: [-1000, 1000], z_mm: [0, 1000]}\n")
    return d


def test_guard_refuses_in_one_line_naming_option_and_size():
    check_allocation("--x", "1 mm", [1000, 1000])  # 8 MB: fine
    with pytest.raises(InputError) as e:
        check_allocation("--pitch-mm", "0.001 mm", [1e6, 1e6], hint="use a coarser --pitch-mm")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("--pitch-mm 0.001 mm: would allocate 7.28 TiB")
    assert "1 000 000 × 1 000 000" in msg and "at most 2 GiB" in msg and "coarser --pitch-mm" in msg
    with pytest.raises(InputError):
        check_allocation("--n", None, [float("inf")])
    assert MAX_ARRAY_BYTES == 2 * 1024 ** 3


def test_serial_grid_step(six, tmp_path):
    out = tmp_path / "x.json"
    refused(olti("identify", six / "sim" / "campaign.csv", "--model", "errormap", "--robot", "ur5", "--tool-frame",
                 "tool0", "--grid-step-deg", "0.001", "--out", out, timeout=30), "--grid-step-deg 0.001", "TiB")
    assert not out.exists()


def test_scara_grid_nodes(tmp_path):
    out = tmp_path / "x.json"
    refused(olti("identify", SCARA, "--model", "errormap", "--grid1-deg=-140:60:0.0001", "--out", out, timeout=30),
            "--grid1-deg", "nodes")
    assert not out.exists()


def test_volumetric_identify_pitch_and_knots(machine, tmp_path):
    out = tmp_path / "x.json"
    campaign = machine / "sim" / "campaign.csv"
    refused(olti("identify", campaign, "--model", "volumetric", "--tool-offsets-mm", TOOLS, "--pitch-mm", "0.00001",
                 "--out", out, timeout=30), "--pitch-mm 1e-05", "GiB")
    refused(olti("identify", campaign, "--model", "volumetric", "--tool-offsets-mm", TOOLS, "--knot-spacing-mm",
                 "0.0000001", "--out", out, timeout=30), "--knot-spacing-mm")
    assert not out.exists()


@pytest.mark.parametrize("option, value, unit", [("--grid-pitch-mm", "0.01", "TiB"), ("--pitch-mm", "0.00001", "GiB")])
def test_volumetric_compensate_tables(machine, tmp_path, option, value, unit):
    out, tables = tmp_path / "c.csv", tmp_path / "tables"
    refused(olti("compensate", machine / "R.json", machine / "want.csv", "--tables", tables, option, value,
                 "--out", out, timeout=30), option, unit)
    assert not out.exists() and not tables.exists()


def test_volumetric_tables_library(machine):
    from olti_drake.io.volumetric_io import load_volumetric_result
    from olti_drake.model.volumetric3d import axis_tables, error_grid

    res = load_volumetric_result(str(machine / "R.json"))
    with pytest.raises(InputError, match="would allocate"):
        error_grid(res.motions, res.model.config, 0.01)
    with pytest.raises(InputError, match="would allocate"):
        axis_tables(res.motions, res.model.config, 1e-7)


def test_3d_scenario_grid(tmp_path):
    text = open(os.path.join(ROOT, "diagrams", "machine_3d.yaml")).read()
    lines = [("grid: [1000, 1000, 1000]" if ln.startswith("grid:") else ln) for ln in text.splitlines()]
    assert any(ln.startswith("grid: [1000") for ln in lines)
    scenario = tmp_path / "big.yaml"
    scenario.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    refused(olti("simulate", scenario, "--out", out, timeout=30), "grid [1000, 1000, 1000]", "TiB")
    assert not out.exists()


def test_machine_grid_commands_library():
    from olti_drake.model.machine import grid_commands_3d
    from olti_drake.model.volumetric3d import MachineConfig

    with pytest.raises(InputError, match="grid"):
        grid_commands_3d(MachineConfig(), (100000, 100000, 1000))


def test_design_serial_step(six, tmp_path):
    out = tmp_path / "d.json"
    refused(olti("design", six / "S.json", "--regions", six / "regions.yaml", "--step-mm", "40", "--out", out,
                 timeout=60), "--step-mm", "GiB")
    refused(olti("design", six / "S.json", "--regions", six / "regions.yaml", "--step-mm", "0.000001", "--out", out,
                 timeout=60), "--step-mm 1e-06", "candidates")
    assert not out.exists()


def test_design_machine_step(machine, tmp_path):
    out = tmp_path / "d.json"
    refused(olti("design", machine / "R.json", "--regions", machine / "regions.yaml", "--step-mm", "40", "--out", out,
                 timeout=60), "--step-mm", "GB")
    refused(olti("design", machine / "R.json", "--regions", machine / "regions.yaml", "--step-mm", "0.000001",
                 "--out", out, timeout=60), "--step-mm 1e-06", "candidates")
    assert not out.exists()


def test_design_scara_steps(tmp_path):
    ident, out = tmp_path / "C.json", tmp_path / "d.json"
    r = olti("identify", SCARA, "--model", "errormap", "--out", ident)
    assert r.returncode == 0, r.stderr
    refused(olti("design", ident, "--regions", REGIONS_2D, "--step-mm", "0.001", "--out", out, timeout=60),
            "--step-mm 0.001")
    refused(olti("design", ident, "--regions", REGIONS_2D, "--workspace-step-mm", "0.001", "--out", out,
                 timeout=60), "--workspace-step-mm 0.001")
    assert not out.exists()


def test_six_axis_scenario_plan_step(tmp_path):
    text = open(os.path.join(ROOT, "diagrams", "six_axis.yaml")).read()
    assert "  step_deg: 15.0" in text
    scenario = tmp_path / "six.yaml"
    scenario.write_text(text.replace("  step_deg: 15.0", "  step_deg: 0.000001"))
    out = tmp_path / "out"
    refused(olti("simulate", scenario, "--out", out, timeout=30), "plan.step_deg 1e-06", "TiB")
    assert not out.exists()


def test_machine_2d_square_targets_library():
    from olti_drake.model.machine import square_targets

    assert len(square_targets(100.0, 20.0)) == 20
    with pytest.raises(InputError, match="step_mm"):
        square_targets(1000.0, 1e-6, perimeter=False)
