"""olti_drake: open-loop tracking interferometer calibration on Drake.

Papers: 000 = Ibaraki & Usui, bidirectional angular positioning deviation error
map of a SCARA robot by "open-loop" tracking interferometer; 001 = the
machine-tool self-calibrated multilateration. Importing this package does not
import pydrake; the modules that need it import it themselves.

The public names below are loaded on first use (module ``__getattr__``), so
``import olti_drake`` stays light::

    import olti_drake as od
    from pydrake.solvers import Solve
    problem = od.calibration_problem("data/paper000/campaign.csv", model="errormap")  # any kind: robot=, machines
    fit = problem.fit()                                   # LM
    same = problem.identification(Solve(problem.prog))    # any solver's result, the same checks and covariance
"""

import importlib

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_PUBLIC = {
    "calibration_problem": "olti_drake.estimation.problem",
    "CalibrationProblem": "olti_drake.estimation.problem",
    "Identification": "olti_drake.estimation.identified",
    "Identifier": "olti_drake.estimation.identification",
    "IdentificationOptions": "olti_drake.estimation.identification",
    "identify": "olti_drake.estimation.identification",
    "load_campaign": "olti_drake.io.csvio",
    "Multilateration": "olti_drake.estimation.multilateration",
    "MultilaterationOptions": "olti_drake.estimation.multilateration",
    "load_machine_campaign": "olti_drake.estimation.multilateration",
    "SolverOptions": "olti_drake.estimation.calibration",
    "LeastSquaresProgram": "olti_drake.estimation.calibration",
    "load_budget": "olti_drake.io.budget",
    "default_budget": "olti_drake.io.budget",
}

__all__ = sorted(_PUBLIC) + ["__version__"]


def __getattr__(name):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value  # once loaded, an ordinary attribute
        return value
    raise AttributeError(f"module 'olti_drake' has no attribute {name!r}")


def __dir__():
    return __all__
