"""Every output of every verb: checked before the work, never a measurement or an input, one line on failure.

Issue 11 (items 3, 5, 8, 10): a campaign or run log is never replaced (not even with --force), a result
only with --force, an input never (hard links included); an output that cannot be written (missing or
unwritable directory, a directory where a file is wanted, a file where a directory is wanted) is one line
``error: ...`` with exit 2 and leaves nothing behind; argparse errors, broken pipes and Ctrl-C during
start-up are one line (or silence) too.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from olti_drake.cli import main
from olti_calls import error_line, olti_in, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")
REGIONS = os.path.join(ROOT, "data", "regions_paper000.yaml")


@pytest.fixture(scope="module")
def result_json(tmp_path_factory):
    """An error-map result of the shipped paper campaign (identified once per module)."""
    path = tmp_path_factory.mktemp("result") / "result.json"
    assert main(["identify", CAMPAIGN, "--model", "errormap", "--out", str(path)]) == 0
    return str(path)


@pytest.fixture
def ws(tmp_path, result_json):
    """A workspace: inputs of every verb, an existing result, a measurement, a plain file, a run dir."""
    d = tmp_path
    shutil.copy(result_json, d / "res.json")
    (d / "cmds.csv").write_text("theta1_deg,theta2_deg,dir1,dir2\n-100,40,1,1\n0,80,-1,1\n")
    (d / "targets.csv").write_text("x_mm,y_mm\n300,200\n350,150\n")
    (d / "old.json").write_text('{"old": true}\n')
    shutil.copy(CAMPAIGN, d / "measured.csv")          # a campaign under another name
    shutil.copy(CAMPAIGN, d / "mcamp.csv")             # an input (never read: the outputs are refused first)
    (d / "afile").write_text("a plain file\n")
    (d / "adir").mkdir()
    (d / "run").mkdir()
    shutil.copy(CAMPAIGN, d / "run" / "campaign.csv")
    os.link(d / "res.json", d / "res_link.json")      # a hard link to an input
    return d


#: verb -> argv before --out (placeholders filled from the workspace)
FILE_VERBS = {
    "identify": ["identify", "{d}/mcamp.csv", "--model", "dh"],
    "predict": ["predict", "{d}/res.json", "{d}/cmds.csv"],
    "uncertainty": ["uncertainty", "{d}/res.json", "{camp}", "--method", "linear"],
    "design": ["design", "{d}/res.json", "--regions", "{regions}"],
    "multilaterate": ["multilaterate", "{d}/mcamp.csv"],
    "compensate": ["compensate", "{d}/res.json", "{d}/targets.csv"],
}
#: --out value -> (extra options, what the one line must say, the file that must stay byte-unchanged)
FILE_CASES = {
    "existing_result": ("{d}/old.json", [], "exists; pass --force", "{d}/old.json"),
    "a_directory": ("{d}/adir", ["--force"], "is a directory", None),
    "missing_directory": ("{d}/nodir/o.json", [], "directory {d}/nodir does not exist", None),
    "under_a_file": ("{d}/afile/o.json", [], "{d}/afile is a file, not a directory", "{d}/afile"),
    "hard_link_to_input": ("{d}/res_link.json", ["--force"], "would overwrite an input file", "{d}/res.json"),
    "a_measurement": ("{d}/measured.csv", ["--force"], "holds measured data", "{d}/measured.csv"),
}


def _fill(items, ws):
    return [str(a).format(d=ws, camp=CAMPAIGN, regions=REGIONS) for a in items]


def _snapshot(ws):
    return {p: p.read_bytes() for p in sorted(ws.rglob("*")) if p.is_file()}


def _check_refused(capsys, ws, argv, message, keep):
    before = _snapshot(ws)
    code, out, err = olti_in(*argv, capsys=capsys)
    error_line(code, err)
    assert _fill([message], ws)[0] in err, err
    assert _snapshot(ws) == before          # nothing written, nothing replaced, no temporary file left
    if keep:
        assert os.path.exists(_fill([keep], ws)[0])


@pytest.mark.parametrize("case", list(FILE_CASES))
@pytest.mark.parametrize("verb", list(FILE_VERBS))
def test_file_outputs_are_checked_before_the_work(capsys, ws, verb, case):
    out, extra, message, keep = FILE_CASES[case]
    if case == "hard_link_to_input" and verb in ("identify", "multilaterate"):
        os.remove(ws / "res_link.json")      # these verbs do not read res.json: link their campaign instead
        os.link(ws / "mcamp.csv", ws / "res_link.json")
    argv = _fill(FILE_VERBS[verb] + ["--out", out] + extra, ws)
    _check_refused(capsys, ws, argv, message, keep)


DIR_CASES = {
    # (argv, message)
    "simulate_existing_campaign": (["simulate", "--out", "{d}/run"], "run/campaign.csv exists and holds measured data"),
    "simulate_out_is_a_file": (["simulate", "--out", "{d}/afile"], "afile is a file, not a directory"),
    "simulate_out_under_a_file": (["simulate", "--out", "{d}/afile/x"], "cannot create directory"),
    "demo_existing_campaign": (["demo", "--out", "{d}/run", "--force"], "holds measured data"),
    "demo_out_is_a_file": (["demo", "--out", "{d}/afile"], "is a file, not a directory"),
    "run_out_is_a_file": (["run", "{scen}", "--out", "{d}/afile"], "is a file, not a directory"),
    "run_existing_log": (["run", "{scen}", "--out", "{d}/logdir"], "logdir/events.jsonl exists and holds measured"),
    "report_out_is_a_file": (["report", "{d}/res.json", "--out", "{d}/afile"], "is a file, not a directory"),
    "report_existing_page": (["report", "{d}/res.json", "--out", "{d}/rep"], "report.html exists; pass --force"),
    "report_input_inside": (["report", "{d}/rep/fig_maps.png", "--out", "{d}/rep", "--force"],
                            "would overwrite an input file"),
    "diagrams_out_is_a_file": (["diagrams", "--out", "{d}/afile"], "is a file, not a directory"),
    "diagrams_existing": (["diagrams", "--out", "{d}/rep"], "paper000_scara.svg exists; pass --force"),
    "compensate_tables_a_file": (["compensate", "{d}/res.json", "{d}/targets.csv", "--out", "{d}/c.csv",
                                  "--tables", "{d}/afile"], "is a file, not a directory"),
    "compensate_tables_exist": (["compensate", "{d}/res.json", "{d}/targets.csv", "--out", "{d}/c.csv",
                                 "--tables", "{d}/rep"], "J1_compensation.csv exists; pass --force"),
    "uncertainty_map_twice": (["uncertainty", "{d}/res.json", "{camp}", "--method", "linear", "--out", "{d}/u.json",
                               "--map", "{d}/u.json"], "named twice as an output"),
    "uncertainty_map_missing_dir": (["uncertainty", "{d}/res.json", "{camp}", "--method", "linear", "--out",
                                     "{d}/u.json", "--maps", "{d}/nodir/m.png"], "directory {d}/nodir does not exist"),
}


@pytest.mark.parametrize("case", list(DIR_CASES))
def test_directory_outputs_are_checked_before_the_work(capsys, ws, case):
    (ws / "logdir").mkdir()
    (ws / "logdir" / "events.jsonl").write_text('{"kind": "session"}\n')
    (ws / "rep").mkdir()
    for name in ("report.html", "fig_maps.png", "paper000_scara.svg", "J1_compensation.csv"):
        (ws / "rep" / name).write_text("an earlier result\n")
    (ws / "scen.yaml").write_text("reflector_estimate: !ExactEstimate {}\nstation: !Simulated {}\n")
    argv, message = DIR_CASES[case]
    argv = [a.format(d=ws, camp=CAMPAIGN, scen=ws / "scen.yaml") for a in argv]
    _check_refused(capsys, ws, argv, message, None)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root writes into read-only directories; the file-under-a-file cases cover it")
def test_a_read_only_directory_is_one_line(capsys, ws):
    ro = ws / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        _check_refused(capsys, ws, ["identify", CAMPAIGN, "--model", "dh", "--out", f"{ro}/r.json"],
                       "is not writable", None)
        _check_refused(capsys, ws, ["simulate", "--out", f"{ro}/sim"], "is not writable", None)
    finally:
        ro.chmod(0o755)


def test_force_replaces_a_result_atomically_and_names_the_written_file(capsys, ws):
    code, out, err = olti_in("identify", CAMPAIGN, "--model", "dh", "--out", ws / "old.json", "--force", capsys=capsys)
    assert code == 0, err
    assert json.loads((ws / "old.json").read_text())["model"] == "dh"
    # --map without .png: the file written is the one named (matplotlib would have added ".png").
    code, out, err = olti_in("uncertainty", ws / "res.json", CAMPAIGN, "--method", "linear", "--out",
                             ws / "u.json", "--map", ws / "umap", capsys=capsys)
    assert code == 0, err
    assert f"wrote {ws / 'umap'}\n" in out and (ws / "umap").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (ws / "umap.png").exists()
    assert not [p for p in ws.iterdir() if p.name.endswith(".tmp")]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    from olti_drake.io import outputs

    path = tmp_path / "r.json"
    path.write_text("old\n")
    with pytest.raises(RuntimeError):
        with outputs.writing(path) as f:
            f.write("half a fi")
            raise RuntimeError("the work failed half way")
    assert path.read_text() == "old\n" and os.listdir(tmp_path) == ["r.json"]

    def full(*a):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "replace", full)
    with pytest.raises(outputs.OutputError, match=r"r\.json: cannot write \(No space left on device\)"):
        outputs.write_json(path, {"new": 1})
    assert path.read_text() == "old\n" and os.listdir(tmp_path) == ["r.json"]


def test_force_never_replaces_what_is_not_a_regular_file(capsys, ws):
    """Data loss class (issue 24): a device node, a FIFO, a socket or a symbolic link given as an output is
    refused even with --force, before any work and again at the rename; nothing is replaced."""
    import socket
    import stat as st

    from olti_drake.io import outputs

    os.mkfifo(ws / "fifo")
    (ws / "target.json").write_text("kept\n")
    os.symlink(ws / "target.json", ws / "link.json")
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(ws / "sock"))
    kinds = {"fifo": "a FIFO", "link.json": "a symbolic link", "sock": "a socket"}
    if os.geteuid() == 0:  # (making a device node needs root: the case of the audit, /dev/null under --force)
        os.mknod(ws / "null", 0o666 | st.S_IFCHR, os.makedev(1, 3))
        kinds["null"] = "a device"
    try:
        for name, what in kinds.items():
            code, out, err = olti_in("identify", CAMPAIGN, "--model", "dh", "--out", ws / name, "--force",
                                     capsys=capsys)
            error_line(code, err)
            assert out == "", (name, out)
            assert f"is {what}, not a regular file" in err, err
        with pytest.raises(outputs.OutputError, match="a FIFO, not a regular file"):
            outputs.write_text(ws / "fifo", "x")  # (the write checks again)
        assert st.S_ISFIFO(os.lstat(ws / "fifo").st_mode) and os.path.islink(ws / "link.json")
        assert (ws / "target.json").read_text() == "kept\n"
        if "null" in kinds:
            assert st.S_ISCHR(os.lstat(ws / "null").st_mode)
    finally:
        sock.close()


def test_a_measurement_is_never_replaced_even_by_a_race(tmp_path):
    """The check before the work is repeated by the write itself: a campaign that appeared meanwhile stays."""
    from olti_drake.io import outputs

    path = tmp_path / "campaign.csv"
    path.write_text("measured\n")
    with pytest.raises(outputs.OutputError, match="never replaces"):
        outputs.write_text(path, "simulated\n", measurement=True)
    assert path.read_text() == "measured\n" and os.listdir(tmp_path) == ["campaign.csv"]


def test_oserror_and_interrupted_import_are_one_line(capsys, monkeypatch):
    """main(): an OSError is one line naming the file; Ctrl-C inside an import (pybind11 turns it into
    ImportError "initialization failed" chained to the KeyboardInterrupt) is "interrupted", exit 130."""
    import olti_drake.cli.verbs as cli

    def denied(args):
        raise PermissionError(13, "Permission denied", "/some/out.json")

    def interrupted_import(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise ImportError("initialization failed") from e

    def real_import_error(args):
        raise ImportError("No module named 'nothing'")

    build = cli.build_parser

    def dispatching_to(func):
        parser = build()
        verbs = next(a for a in parser._actions if a.dest == "verb")
        verbs.choices["predict"].set_defaults(func=func)
        return parser

    argv = ("predict", "r.json", "c.csv", "--out", "p.csv")
    for func, code, text in ((denied, 2, "error: /some/out.json: Permission denied\n"),
                             (interrupted_import, 130, "error: interrupted (olti predict)\n")):
        monkeypatch.setattr(cli, "build_parser", lambda f=func: dispatching_to(f))
        assert olti_in(*argv, capsys=capsys)[::2] == (code, text)
    monkeypatch.setattr(cli, "build_parser", lambda: dispatching_to(real_import_error))
    with pytest.raises(ImportError):            # a real import error is not taken for Ctrl-C
        main(list(argv))


def test_argparse_errors_are_one_line_and_help_still_works():
    r = olti_sub("identify", CAMPAIGN, "--model", "nonsense", "--out", "x.json")
    error_line(r.returncode, r.stderr)
    assert r.stdout == ""
    assert "--model" in r.stderr and "nonsense" in r.stderr
    r = olti_sub()
    error_line(r.returncode, r.stderr)
    r = olti_sub("identify", "--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: olti identify") and r.stderr == ""


def test_a_closed_pipe_ends_quietly(tmp_path, result_json):
    (tmp_path / "cmds.csv").write_text("theta1_deg,theta2_deg,dir1,dir2\n-100,40,1,1\n")
    p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "predict", result_json, str(tmp_path / "cmds.csv"),
                          "--out", str(tmp_path / "p.csv")], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()                          # the reader went away (olti ... | head)
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 1 and err == ""
    assert (tmp_path / "p.csv").exists()


def test_ctrl_c_during_start_up_is_one_line_and_writes_nothing(tmp_path):
    # Ctrl-C as at a terminal: SIGINT at its default even when the tests run in the background (ignored there).
    p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "simulate", "--out", str(tmp_path / "o")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(1.0)                           # inside the imports and the set-up, well before the campaign ends
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    # 130, or death by SIGINT (a shell's $? is 130 too): CPython re-raises SIGINT at exit when a
    # KeyboardInterrupt passed through code run by PyRun_String (pybind11 py::exec in pydrake's imports).
    assert p.returncode in (130, -signal.SIGINT), (out, err)
    assert err == "error: interrupted (olti simulate)\n"
    assert not (tmp_path / "o" / "campaign.csv").exists()


def test_scenario_errors_name_the_field_inside_tagged_subtrees(tmp_path):
    text = open(os.path.join(ROOT, "diagrams", "paper000_scara.yaml"), encoding="utf-8").read()
    cases = {"seed: 0": ("seed: abc", "seed: invalid literal"),
             "amplitude_mdeg: 12.0": ("amplitude_mdeg: xyz", "robot.J1.harmonics[0].amplitude_mdeg:"),
             "theta1_step: 20.0": ("theta1_step: [1]", "plan.theta1_step:")}
    for old, (new, message) in cases.items():
        assert old in text
        (tmp_path / "s.yaml").write_text(text.replace(old, new, 1).replace("../data/", os.path.join(ROOT, "data/")))
        r = olti_sub("simulate", tmp_path / "s.yaml", "--out", tmp_path / "o")
        error_line(r.returncode, r.stderr)
        assert message in r.stderr and "robot: " not in r.stderr, r.stderr


def test_simulate_refuses_a_hardware_scenario_before_opening_a_port(tmp_path):
    (tmp_path / "hw.yaml").write_text("reflector_estimate: !ExactEstimate {}\nstation: !Hardware "
                                      f"{{robot_port: {tmp_path}/robot, counter_port: {tmp_path}/counter}}\n")
    r = olti_sub("simulate", tmp_path / "hw.yaml", "--out", tmp_path / "o")
    error_line(r.returncode, r.stderr)
    assert "runs the simulated station" in r.stderr and "olti run" in r.stderr
    assert not (tmp_path / "o").exists()


def test_demo_into_a_directory_with_a_campaign_is_refused_before_simulating(tmp_path):
    shutil.copy(CAMPAIGN, tmp_path / "campaign.csv")
    before = (tmp_path / "campaign.csv").read_bytes()
    t0 = time.perf_counter()
    r = olti_sub("demo", "--out", tmp_path)
    error_line(r.returncode, r.stderr)
    assert r.stdout == ""
    assert "holds measured data" in r.stderr and time.perf_counter() - t0 < 30
    assert (tmp_path / "campaign.csv").read_bytes() == before and sorted(os.listdir(tmp_path)) == ["campaign.csv"]


@pytest.mark.parametrize("argv", [
    ["identify", "{d}/adir", "--model", "dh", "--out", "{d}/r.json"],
    ["predict", "{d}/res.json", "{d}/adir", "--out", "{d}/p.csv"],
    ["uncertainty", "{d}/adir", "{camp}", "--method", "linear", "--out", "{d}/u.json"],
    ["design", "{d}/res.json", "--regions", "{d}/adir", "--out", "{d}/d.json"],
    ["multilaterate", "{d}/adir", "--out", "{d}/m.json"],
    ["compensate", "{d}/res.json", "{d}/adir", "--out", "{d}/c.csv"],
    ["report", "{d}/res.json", "{d}/adir", "--out", "{d}/rep"],
    ["simulate", "{d}/adir", "--out", "{d}/sim"],
    ["run", "{d}/adir", "--out", "{d}/sim"],
], ids=lambda a: a[0])
def test_a_directory_given_for_an_input_file_is_one_line(capsys, ws, argv):
    before = _snapshot(ws)
    code, out, err = olti_in(*_fill(argv, ws), capsys=capsys)
    error_line(code, err)
    assert f"{ws}/adir: " in err and "directory" in err.lower(), err
    assert _snapshot(ws) == before and not (ws / "sim").exists() and not (ws / "rep").exists()
