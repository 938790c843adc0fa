"""The olti command: fast help, one-line errors, set-up lines in README and .ci/run agree."""

import os
import subprocess
import sys

import pytest
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_help_does_not_import_pydrake():
    code = ("import sys\nfrom olti_drake.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "assert not [m for m in sys.modules if m.startswith(('pydrake', 'numpy', 'matplotlib'))], "
            "sorted(m for m in sys.modules if m.startswith('pydrake'))[:3]\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("verb", ["demo", "simulate", "identify", "predict", "uncertainty", "design", "multilaterate",
                                  "compensate", "run", "report", "diagrams"])
def test_every_verb_has_help(verb):
    r = olti_sub(verb, "--help")
    assert r.returncode == 0 and "--out" in r.stdout


def test_bad_scenario_is_one_line_error(tmp_path):
    bad = tmp_path / "s.yaml"
    bad.write_text("robot: {L1_mm: -1}\n")
    r = olti_sub("simulate", str(bad), "--out", str(tmp_path / "o"))
    error_line(r.returncode, r.stderr, "robot.L1_mm")


def test_bad_plan_file_is_one_line_error(tmp_path):
    (tmp_path / "plan.csv").write_text("theta1_deg,theta2_deg\n0,10\n5,oops\n")
    (tmp_path / "s.yaml").write_text("plan: !PlanFile {path: plan.csv}\n")
    r = olti_sub("simulate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "o"))
    error_line(r.returncode, r.stderr)
    assert "plan.csv" in r.stderr and "3" in r.stderr and "theta2_deg" in r.stderr


def test_refuses_to_overwrite_an_input(tmp_path):
    from olti_drake.io.plan_io import save_plan
    from olti_drake.model.plan import bidirectional_grid
    save_plan(bidirectional_grid(-40, 0, 20, 40, 100, 30), tmp_path / "campaign.csv")
    (tmp_path / "s.yaml").write_text("plan: !PlanFile {path: campaign.csv}\n")
    before = (tmp_path / "campaign.csv").read_bytes()
    r = olti_sub("simulate", str(tmp_path / "s.yaml"), "--out", str(tmp_path))
    assert r.returncode == 2 and "overwrite" in r.stderr
    assert (tmp_path / "campaign.csv").read_bytes() == before


def test_demo_writes_campaign_and_figures(tmp_path):
    r = olti_sub("demo", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "1056" in r.stdout
    for name in ("campaign.csv", "truth.json", "fig5_poses_reflectors.png", "fig6_truth_maps.png"):
        assert (tmp_path / name).stat().st_size > 1000, name


def test_readme_setup_lines_and_ci_agree():
    with open(os.path.join(ROOT, "README.md")) as f:
        lines = [line.strip() for line in f.read().split("```bash", 1)[1].split("```", 1)[0].splitlines()
                 if line.strip()]
    assert len(lines) == 2 and "olti demo" in lines[0] and "pytest" in lines[1]
    with open(os.path.join(ROOT, ".ci", "run")) as f:
        ci = [line.strip() for line in f if line.strip() and not line.startswith("#")]
    assert ci[-1] == lines[1]
