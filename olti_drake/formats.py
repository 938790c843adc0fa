"""Every format id the tool reads or writes (``shared/spec/formats.md``), and the kinds of result document.

At the package top (README "Layout": open to every layer, importing nothing of the package), so that the model's
document parts (``model.volumetric3d``, the simulated truths of ``model.machine``), the writers and loaders in
``io/``, ``estimation/`` and ``report/`` name a format by one constant. What kind a result *file* is -- and the
one-line refusal of anything else -- is :func:`olti_drake.io.documents.result_kind` /
:func:`~olti_drake.io.documents.read_result`.

A result document carries ``"format"`` (below) and, since issue 22, ``"kind"``: one of :data:`RESULT_KINDS`, the
calibration kinds of :data:`olti_drake.estimation.problem.KINDS`. Files written before carry no ``kind``: their
kind is inferred from the format as then (an ``olti-result/1`` with a ``robot`` object is a serial robot's).
"""

#: The SCARA of paper 000 and the N-joint serial robots (told apart by ``kind``; before it, by a ``robot`` object).
ROBOT_RESULT = "olti-result/1"
#: The machine-tool multilateration of paper 001, 2D or 3D.
MULTILATERATION_RESULT = "olti-multilateration/1"
#: The 21 ISO 230-1 error motions of a 3-axis machine.
VOLUMETRIC_RESULT = "olti-volumetric/1"
#: A five-axis machine tool's location errors and rotary-axis error motions (formats.md, "Five-axis machine tools").
MACHINE5_RESULT = "olti-machine5/1"

#: The format of each kind of result document.
RESULT_FORMAT = {"scara": ROBOT_RESULT, "serial": ROBOT_RESULT, "multilateration": MULTILATERATION_RESULT,
                 "volumetric": VOLUMETRIC_RESULT, "machine5": MACHINE5_RESULT}
#: The kinds of result, in the order they are named in messages.
RESULT_KINDS = tuple(RESULT_FORMAT)
#: The result formats (a file whose ``format`` is none of these is not a result).
RESULT_FORMATS = (ROBOT_RESULT, MULTILATERATION_RESULT, VOLUMETRIC_RESULT, MACHINE5_RESULT)
#: What each kind of result is, for messages.
RESULT_WHAT = {"scara": "a SCARA result (olti identify)",
               "serial": "a serial robot's result (olti identify --robot)",
               "multilateration": "a machine-tool multilateration result (olti multilaterate)",
               "volumetric": "a volumetric result (olti identify --model volumetric)",
               "machine5": "a five-axis machine result (olti identify --machine)"}

#: The other documents.
UNCERTAINTY = "olti-uncertainty/1"
#: A simulated five-axis machine's truth (olti simulate diagrams/machine_5axis.yaml: its errors by ISO name).
MACHINE5_TRUTH = "olti-machine5-truth/1"
DESIGN = "olti-design/1"
ISO230 = "olti-iso230/1"
RUN = "olti-run/1"
#: ``olti validate``: K-fold cross-validation by pose of candidate models (estimation.validation).
CROSS_VALIDATION = "olti-cv/1"


def result_header(kind: str) -> dict:
    """The first keys of a result document of ``kind``: ``{"format": ..., "kind": kind}``."""
    return {"format": RESULT_FORMAT[kind], "kind": kind}
