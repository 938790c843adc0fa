"""Moved to :mod:`olti_drake.threads` (model and estimation both use it); kept so old imports work."""

from olti_drake.threads import single_thread_blas  # noqa: F401
