"""BLAS thread control: one thread where threads only cost (small problems, worker processes).

At the package top because both model/ (volumetric3d) and estimation/ use it; it imports nothing of the package.
"""

_BLAS = None
_BLAS_SYMBOLS = [("openblas_get_num_threads", "openblas_set_num_threads"),
                 ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                 ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
                 ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_")]


def _openblas_controls():
    """(get, set) thread-count functions of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    global _BLAS
    if _BLAS is None:
        import ctypes

        _BLAS = []
        try:
            with open("/proc/self/maps", encoding="utf-8") as f:
                paths = sorted({line.split()[-1] for line in f if "openblas" in line.lower() and ".so" in line})
        except OSError:  # not Linux: leave the threads alone
            paths = []
        for path in paths:
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for get, set_ in _BLAS_SYMBOLS:
                if hasattr(lib, get) and hasattr(lib, set_):
                    _BLAS.append((getattr(lib, get), getattr(lib, set_)))
                    break
    return _BLAS


class single_thread_blas:
    """Context manager: OpenBLAS on one thread inside, restored after.

    Small problems (49 x 49) evaluated thousands of times, and worker
    processes that already fill the cores: BLAS threads only add overhead
    there, and on a shared machine their spin-waiting made a design
    evaluation ~10x slower (measured: 48 ms instead of 5 ms per layout).
    """

    def __enter__(self):
        self._saved = [(get(), set_) for get, set_ in _openblas_controls()]
        for _, set_ in self._saved:
            set_(1)
        return self

    def __exit__(self, *exc):
        for n, set_ in self._saved:
            set_(n)
