"""The error every reader, writer and model check raises on bad input: a one-line message for the user
(``error: ...``, exit 2).

At the package top so that every layer raises the same one (README "Layout": the top-level modules are
open to all); it imports nothing of the package. :class:`olti_drake.io.outputs.OutputError` and the
estimation's refusals derive from it.
"""


class InputError(ValueError):
    """Bad input file or parameter; the message is one line, ready for the user."""
