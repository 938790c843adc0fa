"""How the tests call the ``olti`` command line: one copy of each way, for every test file.

* :func:`olti_in` runs it in this process (``olti_drake.cli.main``): fast, and what most tests want. Its output is
  captured on its own, or read from pytest's ``capsys`` when a test passes that fixture (then whatever the test
  printed since its last ``capsys.readouterr()`` is read with it, as a capsys-based test expects).
* :func:`olti_sub` runs ``python -m olti_drake.cli`` in a subprocess: for what only a fresh interpreter shows (the
  modules a verb imports, the exit of the process itself, ``python -m``), for resource limits set in the child
  (``preexec_fn``) and for a guard against a hang (``timeout`` s).

Both can check the exit code (``expect=``): then a run with another code fails the test with the run's stdout and
stderr, a ``Traceback`` on stderr fails it whatever the code, and exit 2 (bad input) must be one stderr line
``error: ...`` (the project's rule for bad input).
"""

import contextlib
import io
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def check_exit(code, out: str, err: str, expect) -> None:
    """With ``expect`` not None: exit code ``expect``, no traceback on stderr, exit 2 = one line ``error: ...``."""
    if expect is None:
        return
    assert code == expect, f"exit {code}, wanted {expect}\n{out}{err}"
    assert "Traceback" not in err, err
    if expect == 2:
        assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err


def error_line(code, err: str, *needles) -> str:
    """A refusal of bad input: exit 2, one stderr line ``error: ...`` (no traceback) that names every needle
    (``str`` of each); returns the line. The one copy of the project's rule for the tests that check a run
    themselves (:func:`check_exit` with ``expect=2`` does the same inside a call)."""
    check_exit(code, "", err, 2)
    for n in needles:
        assert str(n) in err, (n, err)
    return err.strip()


@contextlib.contextmanager
def _in(cwd=None, env=None):
    """This process in the folder ``cwd`` and with the environment variables ``env`` set, restored after."""
    old_cwd, old_env = os.getcwd(), {k: os.environ.get(k) for k in (env or {})}
    try:
        if cwd is not None:
            os.chdir(cwd)
        for k, v in (env or {}).items():
            os.environ[k] = str(v)
        yield
    finally:
        os.chdir(old_cwd)
        for k, v in old_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def olti_in(*argv, capsys=None, cwd=None, env=None, expect=None):
    """``olti ARGV`` in this process: (exit code, stdout, stderr).

    ``argv`` may hold paths and numbers (passed as ``str``); argparse's usage error (its ``SystemExit``) is its exit
    code. ``capsys``: read the output from that pytest fixture instead of capturing it here. ``cwd``: run in that
    folder; ``env``: with those environment variables set (both restored after). ``expect``: see
    :func:`check_exit`."""
    from olti_drake.cli import main

    out, err = io.StringIO(), io.StringIO()
    with _in(cwd, env), contextlib.ExitStack() as stack:
        if capsys is None:
            stack.enter_context(contextlib.redirect_stdout(out))
            stack.enter_context(contextlib.redirect_stderr(err))
        try:
            code = main([str(a) for a in argv])
        except SystemExit as e:
            code = e.code
    out, err = capsys.readouterr() if capsys is not None else (out.getvalue(), err.getvalue())
    check_exit(code, out, err, expect)
    return code, out, err


def olti_sub(*argv, cwd=ROOT, env=None, timeout=600, expect=None, **run):
    """``python -m olti_drake.cli ARGV`` in a subprocess: the ``subprocess.CompletedProcess`` (text stdout, stderr).

    ``argv`` may hold paths and numbers (passed as ``str``). ``cwd``: the child's folder (default the project
    root); the child's environment is this one with ``env``'s variables set and the project root first on
    ``PYTHONPATH`` (the source tree, whatever the folder); ``timeout`` s: a hang fails the test. ``expect``: see
    :func:`check_exit`. Other keywords go to ``subprocess.run`` (e.g. ``preexec_fn``)."""
    environ = dict(os.environ, **{k: str(v) for k, v in (env or {}).items()})
    environ["PYTHONPATH"] = os.pathsep.join(p for p in (ROOT, environ.get("PYTHONPATH")) if p)
    r = subprocess.run([sys.executable, "-m", "olti_drake.cli", *map(str, argv)], capture_output=True, text=True,
                       cwd=cwd, env=environ, timeout=timeout, **run)
    check_exit(r.returncode, r.stdout, r.stderr, expect)
    return r
