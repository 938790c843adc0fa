"""Files the package reads at run time: the shipped scenarios (``diagrams/*.yaml``) and data
(``data/*.yaml``, the paper plan).

One source of truth: the repository's top-level ``diagrams/`` and ``data/`` folders. ``pyproject.toml``
maps them into the package as ``olti_drake/diagrams`` and ``olti_drake/data`` (setuptools
``package-dir``), so a non-editable ``pip install .`` carries them; in a source checkout (or an
editable install) they are read where they are. Relative paths between them (a scenario's
``../data/budget_paper000.yaml``) hold in both layouts.
"""

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # olti_drake/ (this module is olti_drake/io/)


def shipped(*parts: str) -> Path:
    """A shipped file or folder, e.g. ``shipped("data", "budget_paper001.yaml")``: the installed copy
    inside the package if there is one, else the source tree's top-level one."""
    inside = PACKAGE_DIR.joinpath(*parts)
    return inside if inside.exists() else PACKAGE_DIR.parent.joinpath(*parts)


def source_tree_dir(name: str):
    """The top-level folder ``name`` of a source checkout this package runs from, or None when installed."""
    top = PACKAGE_DIR.parent / name
    return top if (PACKAGE_DIR.parent / "pyproject.toml").is_file() and top.is_dir() else None
