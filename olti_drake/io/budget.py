"""Uncertainty budget files (YAML, the schema of :class:`~olti_drake.model.budget.Budget`) and the
default budget of each kind of campaign.

The budget model (contributors, their units, the checks, the per-reading errors) is
:mod:`olti_drake.model.budget`; here a file is read, refused with one line naming the file and the
field when it cannot be right (:meth:`~olti_drake.model.budget.Budget.validate`), and the papers' own
tables are chosen when no file is named.
"""

import copy
import os

from olti_drake.errors import InputError
from olti_drake.model.budget import Budget, check_stated, paper000_budget


def load_budget(path) -> Budget:
    """Load a budget YAML file (schema :class:`Budget`); errors name the file and field."""
    from pydrake.common.yaml import yaml_load_typed  # lazy: keeps `olti --help` fast

    from olti_drake.io.csvio import read_yaml

    name = os.fspath(path)
    raw = read_yaml(name, "budget")  # refuses duplicate keys and non-UTF-8 bytes, naming the line
    try:
        budget = yaml_load_typed(schema=Budget, filename=name, allow_schema_with_no_yaml=True)
    except Exception as e:  # pydrake raises RuntimeError/TypeError with multi-line text
        raise InputError(f"{name}: {str(e).splitlines()[0]}") from None
    budget.validate(name)
    check_stated(raw.get("contributors") if isinstance(raw, dict) else None, name)  # no unit, k, acts_on by default
    return budget


#: The budget each kind of campaign is propagated with when none is named: the papers' own tables.
DEFAULT_BUDGETS = {"scara": "000 Table 2 (k = 1), built in", "machine": "001 Table 4 (k = 2), data/budget_paper001.yaml"}


#: The shipped budget files, read once: {kind: Budget}.
_SHIPPED = {}


def default_budget(kind: str) -> Budget:
    """The one place the default budget is chosen: ``scara`` -> 000 Table 2, ``machine`` -> 001 Table 4.

    Used by the identification's residual check, the multilateration, the CLI verbs and the report.
    """
    if kind == "scara":
        return paper000_budget()
    if kind == "machine":
        from olti_drake.io.resources import shipped

        if kind not in _SHIPPED:  # (parsed once per process: a five-axis fit asked twice, 60 of its 140 ms)
            _SHIPPED[kind] = load_budget(shipped("data", "budget_paper001.yaml"))
        return copy.deepcopy(_SHIPPED[kind])  # (a caller's changes stay its own)
    raise InputError(f"budget kind must be one of {', '.join(DEFAULT_BUDGETS)}, got {kind!r}")


def budget_or_default(path, kind: str) -> Budget:
    """The budget file ``path`` if given (a CLI's ``--budget``), else :func:`default_budget` of ``kind``."""
    return load_budget(path) if path else default_budget(kind)
