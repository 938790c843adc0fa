"""The position-model protocol of the one calibration engine (issue 22): what a robot or machine offers the
measurements of :mod:`olti_drake.model.measurements` (the distance from stations of 000 Eq. 10 / 001 Eq. 3).

A position model maps its parameter vector x (named :attr:`~PositionModel.names`, model units: mm, deg, µrad
as named) to the points the readings see, one per row of its commands (the reflector of a SCARA pose, a target
of 001, a machine's tool point), in :attr:`~PositionModel.dim` = 2 or 3 dimensions, mm. Implementations:

* :class:`olti_drake.model.scara.ScaraPositionModel` -- the SCARA of 000 in closed form (Eq. 3; Eq. 7 for the
  error maps), the fast path and the oracle of the general chain;
* :class:`olti_drake.model.free_points.FreePoints` -- the free targets of 001's multilateration (2D/3D, tool
  offsets);
* :class:`olti_drake.model.volumetric3d.VolumetricPositionModel` -- the 21 ISO 230-1 motions of a 3-axis machine.

The N-joint chain (:class:`olti_drake.model.serial.SerialPositionModel`) takes its commands at each call and is
read by its own measurements (:mod:`olti_drake.model.serial`: distance with drift and planar stations, tracker
points, root positions); it joins this protocol when those measurements move here.
"""

from typing import Protocol, Tuple, runtime_checkable

import numpy as np


@runtime_checkable
class PositionModel(Protocol):
    """What :class:`~olti_drake.model.measurements.StationDistanceMeasurement` reads of a model."""

    #: The parameters, in the order of x (their units in their names: ``L1_mm``, ``J1_forward_deg[3]``, ``E_XX``).
    names: Tuple[str, ...]
    #: 2 (the SCARA, 001's table) or 3.
    dim: int

    @property
    def n_params(self) -> int:
        """len(names)."""

    @property
    def n_points(self) -> int:
        """Points (command rows) the model places."""

    def start_vector(self) -> np.ndarray:
        """The start (nominal) parameter vector x0, model units."""

    def positions(self, x=None) -> np.ndarray:
        """(n_points, dim) mm at x (default the start)."""

    def jacobian(self, x=None):
        """(positions, J): J a row-compressed Jacobian with ``tocsr()`` ((n_points·dim, n) sparse, rows point-major)
        and ``contract(u)`` (u (n_points, dim) -> the sparse (n_points, n) rows uᵀ ∂p/∂x)."""

    def rows(self, X, points):
        """Batched for T parameter vectors X (T, n): (p (T, K, dim), cols (K, m), dp (dim of (T, K, m))) at the
        point indices ``points`` (K,) -- the columns shared by the trials (the Monte Carlo's fast path)."""

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector in the result document's keys and shapes (formats.md)."""

    def implausible(self, x) -> list:
        """Physically impossible values of x, one phrase each (empty: plausible)."""
