"""A non-editable install carries what the verbs read at run time (issue 11, item 10).

The shipped scenarios (``diagrams/*.yaml``) and data (``data/*.yaml``) live once, in the top-level
folders; ``pyproject.toml`` maps them into the package. This builds the installed layout the way a
``pip install .`` does (setuptools ``build_py``: packages and package data, no network) from a copy of
the source, then runs ``olti diagrams`` and ``olti demo`` from it with the source tree out of reach.
"""

import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    src, lib = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("lib")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(os.path.join(ROOT, name), src / name)
    for name in ("olti_drake", "diagrams", "data"):
        shutil.copytree(os.path.join(ROOT, name), src / name, ignore=shutil.ignore_patterns("__pycache__"))
    r = subprocess.run([sys.executable, "-c", "import setuptools; setuptools.setup()", "-q", "build_py", "-d",
                        str(lib)], cwd=src, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return lib


def _olti(lib, cwd, *args):
    env = dict(os.environ, PYTHONPATH=str(lib))     # the installed package only, not the source tree
    return subprocess.run([sys.executable, "-m", "olti_drake.cli", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


def test_the_installed_package_holds_its_run_time_files(installed):
    pkg = installed / "olti_drake"
    for rel in ("diagrams/paper000_scara.yaml", "diagrams/paper000_emulated.yaml", "diagrams/paper000_hardware.yaml",
                "data/budget_paper000.yaml", "data/budget_paper001.yaml", "data/regions_paper000.yaml",
                "models/scara.sdf"):
        with open(os.path.join(ROOT, rel.replace("models/", "olti_drake/models/")), "rb") as f:
            assert (pkg / rel).read_bytes() == f.read(), rel
    code = ("import olti_drake, olti_drake.io.budget as b, olti_drake.report.diagram_pictures as d; "
            "print(olti_drake.__file__); print(d.DIAGRAMS_DIR); print(b.default_budget('machine').name)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=installed,
                       env=dict(os.environ, PYTHONPATH=str(installed)))
    assert r.returncode == 0, r.stderr
    module, diagrams, budget = r.stdout.splitlines()
    assert module.startswith(str(installed)) and diagrams == str(pkg / "diagrams") and budget


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz dot not installed (apt-get install graphviz)")
def test_diagrams_from_the_installed_package(installed, tmp_path):
    r = _olti(installed, tmp_path, "diagrams", "--out", "pictures")
    assert r.returncode == 0, r.stderr
    for name in ("paper000_scara", "paper000_emulated", "paper000_hardware"):
        assert (tmp_path / "pictures" / f"{name}.svg").stat().st_size > 1000
        with open(os.path.join(ROOT, "diagrams", f"{name}.wiring.txt"), encoding="utf-8") as f:
            assert (tmp_path / "pictures" / f"{name}.wiring.txt").read_text(encoding="utf-8") == f.read()
    r = _olti(installed, tmp_path, "diagrams")          # no source checkout to default to
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "--out" in r.stderr


def test_demo_from_the_installed_package(installed, tmp_path):
    r = _olti(installed, tmp_path, "demo", "--out", "demo")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "demo" / "result_errormap.json").is_file() and (tmp_path / "demo" / "campaign.csv").is_file()
