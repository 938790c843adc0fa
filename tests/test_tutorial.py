"""docs/tutorial.md runs as written: every ```bash block, in order, in one scratch directory.

The convention (also stated in an HTML comment at the top of the tutorial):

- ```bash            run, in order, with ``set -euo pipefail``; must exit 0;
- ```bash-needs-dot  run like ```bash when Graphviz ``dot`` is installed, skipped otherwise;
- ```bash-norun      never run (installation, real hardware, interactive sessions);
- anything else (```text, ```yaml, ...) is sample output or a file excerpt.

The scratch directory holds symlinks to the repository's ``diagrams/``, ``data/`` and
``examples/``, so the commands read exactly the paths a reader types at the repository root
and everything they write lands in the scratch ``work/``; the repository is checked unchanged.
After the blocks, the main outputs and the numbers the tutorial quotes are checked.
"""

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
LINKED = ("diagrams", "data", "examples")
RUN, NEEDS_DOT, NORUN = "bash", "bash-needs-dot", "bash-norun"
FENCE = re.compile(r"^```([^\s`]*)\s*$")


def code_blocks(text):
    """[(info, code, first line number)] of the fenced blocks of a Markdown text."""
    blocks, info, start, lines = [], None, 0, []
    for n, line in enumerate(text.splitlines(), 1):
        m = FENCE.match(line)
        if info is None:
            if m:
                info, start, lines = m.group(1), n, []
        elif line.rstrip() == "```":
            blocks.append((info, "\n".join(lines) + "\n", start))
            info = None
        else:
            lines.append(line)
    assert info is None, f"docs/tutorial.md: the block opened at line {start} is never closed"
    return blocks


BLOCKS = [b for b in code_blocks(TUTORIAL.read_text(encoding="utf-8")) if b[0] in (RUN, NEEDS_DOT)]


def snapshot():
    """Names, sizes and mtimes of every file under the linked repository folders."""
    out = {}
    for name in LINKED:
        for p in (ROOT / name).rglob("*"):
            if p.is_file() and "__pycache__" not in p.parts:
                st = p.stat()
                out[str(p.relative_to(ROOT))] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """The reader's working directory: symlinks to diagrams/, data/, examples/; nothing else."""
    d = tmp_path_factory.mktemp("tutorial")
    for name in LINKED:
        (d / name).symlink_to(ROOT / name, target_is_directory=True)
    env = dict(os.environ, MPLBACKEND="Agg")
    # `olti` and `python` of this interpreter's environment first on PATH.
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    state = {"dir": d, "env": env, "failed": None, "out": {}}
    before = snapshot()
    yield state
    assert snapshot() == before, "the tutorial's commands changed files in the repository"


def test_tutorial_conventions():
    text = TUTORIAL.read_text(encoding="utf-8")
    assert text.startswith("<!--") and "bash-norun" in text.split("-->")[0], \
        "the fence convention must be stated in the HTML comment at the top"
    blocks = code_blocks(text)
    infos = {info for info, _, _ in blocks}
    unknown = {i for i in infos if i.startswith("bash")} - {RUN, NEEDS_DOT, NORUN}
    assert not unknown, f"unknown bash fence info strings {unknown}"
    assert sum(info == RUN for info, _, _ in blocks) >= 8
    norun = "".join(code for info, code, _ in blocks if info == NORUN)
    assert "pip install -e ." in norun and "--meshcat" in norun and "olti run my_robot.yaml" in norun
    for info, code, line in blocks:
        if info in (RUN, NEEDS_DOT):
            assert "pip install" not in code, f"line {line}: installation must not run in the test"
            for m in re.finditer(r"--out\s+(\S+)|(?<![-=>])>>?\s*([^\s;|&)]+)", code):
                target = m.group(1) or m.group(2)
                assert target.startswith("work/") or target.startswith("/dev/null"), \
                    f"line {line}: writes {target} outside work/"


@pytest.mark.parametrize("info,code,line", BLOCKS, ids=[f"line{b[2]}" for b in BLOCKS])
def test_block(scratch, info, code, line):
    if scratch["failed"] is not None:
        pytest.skip(f"an earlier block failed (line {scratch['failed']})")
    if info == NEEDS_DOT and shutil.which("dot") is None:
        pytest.skip("Graphviz `dot` is not installed (apt-get install graphviz)")
    try:
        proc = subprocess.run(["bash", "-c", "set -euo pipefail\n" + code], cwd=scratch["dir"],
                              env=scratch["env"], capture_output=True, text=True, timeout=180)
    except subprocess.TimeoutExpired:
        scratch["failed"] = line
        raise
    scratch["out"][line] = proc.stdout + proc.stderr
    if proc.returncode != 0:
        scratch["failed"] = line
    assert proc.returncode == 0, (f"docs/tutorial.md block at line {line} exited {proc.returncode}\n"
                                  f"--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}")


def _block_output(scratch, needle):
    for info, code, line in BLOCKS:
        if needle in code:
            return scratch["out"].get(line)
    raise AssertionError(f"no block of docs/tutorial.md contains {needle!r}")


def _readings(path):
    with open(path, encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def test_outputs(scratch):
    """What the blocks made, and the numbers the tutorial quotes (update the prose with them)."""
    if scratch["failed"] is not None:
        pytest.skip(f"a block failed (line {scratch['failed']})")
    w = scratch["dir"] / "work"
    for name in ("sim/campaign.csv", "sim/truth.json", "pred_errormap.csv", "pred_dh.csv",
                 "unc_linear.json", "unc_mc.json", "maps.png", "u_map.png", "comp_commands.csv",
                 "tables/J1_compensation.csv", "tables/J2_compensation.csv", "report/report.html",
                 "report/iso230.json", "run/run.json", "run/events.jsonl",
                 "run/truth.json", "run/result_errormap.json", "run/report/report.html",
                 "py/result_errormap.json"):
        assert (w / name).is_file(), f"work/{name} missing"
    if shutil.which("dot") is not None:
        assert (w / "diagrams" / "paper000_emulated.svg").is_file()

    dh = json.loads((w / "sim/result_dh.json").read_text())
    em = json.loads((w / "sim/result_errormap.json").read_text())
    assert dh["model"] == "dh" and em["model"] == "errormap"
    assert abs(1e3 * em["residual_rms_mm"] - 15.63) < 0.3      # "residual RMS 15.63 um"
    assert abs(1e3 * dh["residual_rms_mm"] - 51.53) < 1.0      # "residual RMS 51.53 um"
    assert abs(em["L1_mm"] - 324.9735) < 0.002

    pred = _readings(w / "pred_errormap.csv")
    gap = float(pred[0]["y_mm"]) - float(pred[1]["y_mm"])     # "0.158 mm apart"
    assert abs(gap - 0.158) < 0.02
    dh_pred = _readings(w / "pred_dh.csv")
    assert dh_pred[0]["y_mm"] == dh_pred[1]["y_mm"]

    unc = json.loads((w / "unc_linear.json").read_text())
    assert abs(1e3 * unc["prediction_expanded_mm"]["max"] - 28.0) < 2.0
    assert abs(1e3 * unc["reading_std_median_mm"] - 15.8) < 0.3
    assert json.loads((w / "unc_mc.json").read_text())["trials"] == 200

    assert len(_readings(w / "comp_commands.csv")) == 4
    iso = json.loads((w / "report/iso230.json").read_text())["axes"]
    assert abs(1e3 * iso["J1"]["E_deg"] - 40.5) < 1.5 and abs(1e3 * iso["J2"]["E_deg"] - 39.8) < 1.5

    # The interrupted and resumed emulated run: 130 on SIGINT with the resume hint, all readings
    # on disk once, from three sessions.
    out = _block_output(scratch, "kill -INT")
    assert "exited with status 130" in out and "exited with status 137" in out
    assert "continue with: olti run diagrams/paper000_emulated.yaml --out work/run --resume" in out
    rows = _readings(w / "run/campaign.csv")
    steps = [int(r["step"]) for r in rows]
    assert len(rows) == 1056 and len(set(steps)) == 1056 and steps == sorted(steps)
    assert {r["session"] for r in rows} == {"0", "1", "2"}
    run = json.loads((w / "run/run.json").read_text())
    assert run["sessions"][0]["outcome"] == "interrupted (SIGINT)"  # the kill -9'd one never ended
    assert run["sessions"][-1]["outcome"] == "complete"
    assert abs(1e3 * json.loads((w / "run/result_errormap.json").read_text())["residual_rms_mm"] - 15.4) < 1.0
