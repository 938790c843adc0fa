"""The error every reader and writer raises: a one-line message for the user (``error: ...``, exit 2).

Its own module so that :mod:`olti_drake.io.csvio` and :mod:`olti_drake.io.outputs` (which import each
other's functions otherwise) both build on it without an import circle.
"""


class InputError(ValueError):
    """Bad input file or parameter; the message is one line, ready for the user."""
