"""The kind of a result document, and the one reader of any result file (issue 22).

Every result the tool writes names its format and its kind (:mod:`olti_drake.formats`: the format ids, the
kinds). :func:`result_kind` tells the kind of a document -- from its ``kind`` key, or, for the files written
before that key (``olti-result/1``, ``olti-multilateration/1``, ``olti-volumetric/1`` without ``kind``), from the
format as then: an ``olti-result/1`` with a ``robot`` object is a serial robot's, without one a SCARA's.
Anything else is refused in one line naming the file. :func:`read_result` reads a file and returns
``(kind, document)``; every verb that takes a result dispatches on that kind once. The kind's own loader
(``io.result.load_result``, ``io.serial_io.load_serial_result``, ``estimation.multilateration.load_result``,
``io.volumetric_io.load_volumetric_result``) then checks the schema where it reads it.
"""

import os

from olti_drake.errors import InputError
from olti_drake.formats import (MULTILATERATION_RESULT, RESULT_FORMAT, RESULT_FORMATS, RESULT_KINDS, RESULT_WHAT,
                                ROBOT_RESULT, VOLUMETRIC_RESULT)

#: The kind of a result file written before the ``kind`` key, by its format (``olti-result/1``: see
#: :func:`result_kind`).
_LEGACY_KIND = {ROBOT_RESULT: "scara", MULTILATERATION_RESULT: "multilateration", VOLUMETRIC_RESULT: "volumetric"}
#: Kinds as a verb's message lists them.
_NAMES = {"scara": "SCARA", "serial": "serial-robot", "multilateration": "multilateration", "volumetric": "volumetric"}


def _either(words) -> str:
    words = list(words)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def kinds_text(kinds) -> str:
    """'SCARA, serial-robot and volumetric results' (for messages)."""
    names = [_NAMES[k] for k in kinds]
    return (names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]) + " results"


def result_kind(doc, name) -> str:
    """``"scara"``, ``"serial"``, ``"multilateration"`` or ``"volumetric"``: the kind of the result document
    ``doc`` read from the file ``name`` (module doc); InputError (one line naming the file) for a document that is
    not a result, an unknown ``kind``, or a ``kind`` its ``format`` does not carry."""
    name = os.fspath(name)
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt not in RESULT_FORMATS:
        raise InputError(f"{name}: 'format' must be {_either(repr(f) for f in RESULT_FORMATS)} for a result, "
                         f"got {fmt!r}")
    if "kind" not in doc:  # written before the 'kind' key: the kind as it was told then
        return "serial" if fmt == ROBOT_RESULT and isinstance(doc.get("robot"), dict) else _LEGACY_KIND[fmt]
    kind = doc["kind"]
    if kind not in RESULT_KINDS:
        raise InputError(f"{name}: key 'kind': unknown result kind {kind!r} (expected "
                         f"{_either(repr(k) for k in RESULT_KINDS)})")
    if RESULT_FORMAT[kind] != fmt:
        raise InputError(f"{name}: key 'kind' {kind!r} does not go with 'format' {fmt!r} (a {kind} result is "
                         f"{RESULT_FORMAT[kind]!r})")
    return kind


def read_result(path, kinds=None, user: str = "", refuse: bool = True) -> tuple:
    """``(kind, document)`` of any result file (JSON, checked as every JSON file; :func:`result_kind`).

    ``kinds``: the kinds the caller takes (a file that is not JSON is told which); another kind is refused
    (unless not ``refuse``) in one line naming the file, its kind and format, and what ``user`` (e.g.
    ``"olti predict"``) takes."""
    from olti_drake.io.csvio import read_json

    doc = read_json(path, None, _either(RESULT_WHAT[k] for k in kinds) if kinds else "a result")
    kind = result_kind(doc, path)
    if refuse and kinds is not None and kind not in kinds:
        raise not_taken(path, kind, doc, kinds, user)
    return kind, doc


def not_taken(path, kind: str, doc: dict, kinds, user: str = "") -> InputError:
    """The one-line refusal of a result of ``kind`` by a ``user`` that takes ``kinds`` only."""
    return InputError(f"{os.fspath(path)}: {RESULT_WHAT[kind]}, 'format' {doc['format']!r}: {user or 'this'} takes "
                      f"{kinds_text(kinds)}")


def with_kind(kind: str, doc: dict) -> dict:
    """``doc`` as a result of ``kind`` is written: ``format`` and ``kind`` first, then the rest in order."""
    if doc.get("format", RESULT_FORMAT[kind]) != RESULT_FORMAT[kind]:
        raise ValueError(f"a {kind} result is {RESULT_FORMAT[kind]!r}, not {doc['format']!r}")
    return {"format": RESULT_FORMAT[kind], "kind": kind, **{k: v for k, v in doc.items() if k not in
                                                             ("format", "kind")}}
