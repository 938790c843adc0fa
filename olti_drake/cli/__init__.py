"""cli: the ``olti`` command: argument parsing and dispatch only (``olti_drake.cli.verbs``);
the numeric option types in ``olti_drake.cli.args``. Importing it imports argparse only."""

from olti_drake.cli.verbs import main

__all__ = ["main"]
