"""One identification type for every kind of calibration (issue 22, items 2 and 3).

:meth:`CalibrationProblem.fit() <olti_drake.estimation.problem.CalibrationProblem.fit>` and
:meth:`CalibrationProblem.identification(result) <olti_drake.estimation.problem.CalibrationProblem.identification>`
return an :class:`Identification` whatever the kind -- the SCARA of 000, an N-joint robot, the multilateration of
001, the volumetric machine, a five-axis machine::

    fit = od.calibration_problem("campaign.csv", model="errormap", robot="ur5", tool_frame="tool0").fit()
    fit.kind, fit.values()["L1_mm"], fit.uncertainties()["L1_mm"]   # mm; k = 1
    fit.write("result.json")                                           # the file ``olti identify`` writes

How a kind's own result gives the fit and the document is the kind's entry in
:data:`olti_drake.estimation.problem.KINDS` (``Kind.fit``, ``Kind.document``): the one place.
"""

import os
from typing import Optional

import numpy as np


class Identification:
    """An identified calibration of any kind (module doc).

    Fields (units are in the parameter names: ``_mm`` mm, ``_deg`` degrees, ``_urad`` µrad):

    * ``kind``: the kind's name in :data:`~olti_drake.estimation.problem.KINDS` (``scara``, ``serial``,
      ``multilateration``, ``volumetric``, ``machine5``).
    * ``names``: the parameter names (the program's unknowns, in its order: the model's, then the stations',
      dead paths' or frames' of the kind).
    * ``x``: the identified values (N,), in the names' units.
    * ``std``: their standard uncertainties (k = 1, linear propagation, JCGM 100), same units.
    * ``covariance``: (N, N) covariance of ``x`` (k = 1; the units' products), formed when first read on large
      problems.
    * ``residuals``: the readings' residuals (mm), in the campaign's order.
    * ``notes``, ``warnings``: what the fit said (stated facts; doubts that did not refuse it).
    * ``converged_by``: the criterion by which the solver stopped; ``solver``: which solved it (``given: ...``
      when another solver's result was turned back by ``identification``).
    * ``lack_of_fit_mm``: the model error (mm, k = 1) every prediction shares (0 where the kind states none).
    * ``extra``: the user's own decision variables added to ``problem.prog``, by name: their solved values.
    * ``result``: the kind's own result object (the SCARA ``Identification``, ``SerialIdentification``,
      ``MultilaterationResult``, ``VolumetricResult``, the five-axis engine ``Fit``).

    For compatibility with code written against the kinds' own results, an attribute this class does not define
    is read from ``result`` (``fit.reflectors_mm``, ``fit.measurement``, ``fit.targets_mm``, ``fit.solver``,
    ...); new code should use the fields above, which are the same for every kind."""

    def __init__(self, kind, result, problem=None):
        # ``kind``: the kind's entry in KINDS (given, not looked up: this module sits below problem.py)
        self.kind, self.result, self._problem = kind.name, result, problem
        self._kind = kind
        fit = self._fit = self._kind.fit(result)
        self.names = list(fit.names)
        self.x = np.asarray(fit.x, dtype=float)
        self.std = np.asarray(fit.std, dtype=float)
        residuals = getattr(fit, "residuals", None)  # (the SCARA's Identification names them residuals_mm)
        self.residuals = np.asarray(fit.residuals_mm if residuals is None else residuals, dtype=float)
        # The fit's notes, then what the kind's result says beyond them (the serial result's regularization
        # and rebuild notes live on it, not on the engine's fit).
        own = [] if result is fit else [n for n in getattr(result, "notes", None) or [] if n not in fit.notes]
        self.notes, self.warnings = list(fit.notes) + own, list(fit.warnings)
        self.converged_by, self.solver = fit.converged_by, str(getattr(fit, "solver", "") or "")
        self.lack_of_fit_mm = float(getattr(fit, "lack_of_fit_mm", 0.0) or 0.0)
        self.extra = dict(getattr(fit, "extra", None) or {})

    @property
    def covariance(self) -> np.ndarray:
        """(N, N) covariance of :attr:`x` (k = 1), the fit's own (formed on first read where it is deferred)."""
        return self._fit.covariance

    def __getattr__(self, name):
        # Compatibility (class doc): what Identification does not define is the kind's own result's.
        if name.startswith("__") or name in ("result", "_fit", "_kind", "_problem"):
            raise AttributeError(name)
        try:
            result = self.__dict__["result"]
        except KeyError:
            raise AttributeError(name) from None
        return getattr(result, name)

    def __repr__(self) -> str:
        return f"Identification(kind={self.kind!r}, {len(self.names)} parameters, converged by {self.converged_by!r})"

    def values(self) -> dict:
        """name -> identified value (the unit in the name: mm, deg, µrad)."""
        return {n: float(v) for n, v in zip(self.names, self.x)}

    def uncertainties(self) -> dict:
        """name -> standard uncertainty (k = 1; the unit in the name)."""
        return {n: float(v) for n, v in zip(self.names, self.std)}

    def document(self, path: Optional[str] = None) -> dict:
        """The result document, exactly as ``olti identify`` writes it for this kind (formats.md: ``format`` and
        ``kind``), by the kind's own writer in :mod:`olti_drake.io` (``Kind.document``). ``path``: where it is to
        be written -- the files it names (a robot or machine model, a ``linear`` result) are given relative to
        its folder, as the command line gives them relative to ``--out``; default ``result.json`` in the current
        folder."""
        if self._problem is None:
            raise ValueError("an Identification made without its CalibrationProblem has no document")
        path = os.fspath(path) if path is not None else os.path.join(os.getcwd(), "result.json")
        return self._kind.document(self.result, self._problem, path)

    def write(self, path, force: bool = False) -> str:
        """Write :meth:`document` to ``path`` as JSON (atomically, as ``olti identify``). An existing file is
        refused in one line (:class:`~olti_drake.io.outputs.OutputError`) and left as it is, unless ``force``;
        a campaign or an input of the calibration is never replaced. Returns the path."""
        from olti_drake.io.outputs import preflight, write_json

        inputs = self._problem.inputs() if self._problem is not None else []
        preflight([path], inputs, force=force)
        return write_json(path, self.document(path))
