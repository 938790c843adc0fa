"""The suite's one set-up: each pytest-xdist worker (pyproject: ``-n auto``) keeps BLAS on one thread.

Two workers on a 2-core CI machine already fill it; BLAS threads on top only contend (the subprocesses the
CLI tests start inherit the setting). Set before numpy loads in the worker; a value given by the caller wins.
This file's folder is on ``sys.path`` (pytest's rootdir-conftest rule), so the helper modules here
(``numeric_files``, ``figure_capture``, ``memory_devices``) import from any test folder below it.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
