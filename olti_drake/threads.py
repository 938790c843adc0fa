"""Threads: BLAS thread control (one thread where threads only cost -- small problems, worker processes --,
all of them for one large factorization), BLAS/LAPACK calls that release the GIL (for work beside the
solver in a helper thread), and :func:`in_parallel` for GIL-releasing numpy/scipy.sparse work.

At the package top because both model/ (volumetric3d) and estimation/ use it; it imports nothing of the package.
"""

_BLAS = None
_STARTED = []  # each OpenBLAS's thread count when first seen (before any context changed it)
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
                    _STARTED.append(_BLAS[-1][0]())
                    break
    return _BLAS


class blas_threads:
    """Context manager: OpenBLAS on ``n`` threads inside (None: as many as the process started with), restored
    after."""

    def __init__(self, n=None):
        self.n = n

    def __enter__(self):
        controls = _openblas_controls()
        self._saved = [(get(), set_) for get, set_ in controls]
        for (_, set_), start in zip(controls, _STARTED):
            set_(start if self.n is None else self.n)
        return self

    def __exit__(self, *exc):
        for n, set_ in self._saved:
            set_(n)


class single_thread_blas(blas_threads):
    """Context manager: OpenBLAS on one thread inside, restored after.

    Small problems (49 x 49) evaluated thousands of times, and worker
    processes that already fill the cores: BLAS threads only add overhead
    there, and on a shared machine their spin-waiting made a design
    evaluation ~10x slower (measured: 48 ms instead of 5 ms per layout).
    """

    def __init__(self):
        super().__init__(1)


# -- BLAS and LAPACK calls that release the GIL ----------------------------------------------------
# scipy.linalg's f2py wrappers hold the GIL through the Fortran call for routines not declared thread-safe
# (measured: dsymv, strtri, dtrtri, dpotrf block every other Python thread for their whole run). A helper
# thread doing seconds of such algebra beside the solver then stalls the solver's evaluations 2-3x. The same
# routines, called through scipy's cython_blas / cython_lapack function pointers with ctypes, release it.
_NOGIL = {}


def _nogil(module: str, name: str, *argtypes):
    """scipy's BLAS/LAPACK routine ``name`` (``module`` cython_blas or cython_lapack) as a ctypes function
    that releases the GIL (CFUNCTYPE), or None when scipy does not expose it so."""
    import ctypes
    import importlib

    if name not in _NOGIL:
        try:
            capsule = importlib.import_module(f"scipy.linalg.{module}").__pyx_capi__[name]
            get_name, get_pointer = ctypes.pythonapi.PyCapsule_GetName, ctypes.pythonapi.PyCapsule_GetPointer
            get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
            get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
            _NOGIL[name] = ctypes.CFUNCTYPE(None, *argtypes)(get_pointer(capsule, get_name(capsule)))
        except Exception:  # another scipy layout: the f2py wrapper serves
            _NOGIL[name] = None
    return _NOGIL[name]


def triangular_inverse(U, dtype):
    """(U⁻¹, info): U's upper triangle inverted in ``dtype`` (float32 or float64) by LAPACK ?trtri, Fortran
    order; the strict lower triangle is U's (converted), untouched. Releases the GIL while LAPACK runs."""
    import ctypes

    import numpy as np

    name = "strtri" if np.dtype(dtype) == np.float32 else "dtrtri"
    i = ctypes.POINTER(ctypes.c_int)
    routine = _nogil("cython_lapack", name, ctypes.c_char_p, ctypes.c_char_p, i, ctypes.c_void_p, i, i)
    a = np.array(U, dtype=dtype, order="F")
    if routine is None:
        from scipy.linalg import lapack

        return getattr(lapack, name)(a, lower=0, overwrite_c=1)
    n, info = ctypes.c_int(a.shape[0]), ctypes.c_int(0)
    routine(b"U", b"N", ctypes.byref(n), a.ctypes.data, ctypes.byref(n), ctypes.byref(info))
    return a, info.value


def symmetric_times(A, v):
    """A v for a symmetric A (n, n) stored in its lower triangle, Fortran order, float64 (the upper triangle
    is not read): BLAS dsymv, releasing the GIL."""
    import ctypes

    import numpy as np

    d, i = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
    routine = _nogil("cython_blas", "dsymv", ctypes.c_char_p, i, d, ctypes.c_void_p, i, ctypes.c_void_p, i, d,
                     ctypes.c_void_p, i)
    if routine is None or not (A.flags.f_contiguous and A.dtype == np.float64):
        from scipy.linalg import blas

        return blas.dsymv(1.0, A, v, lower=1)
    x = np.ascontiguousarray(v, dtype=np.float64)
    y = np.zeros_like(x)
    n, one = ctypes.c_int(A.shape[0]), ctypes.c_int(1)
    alpha, beta = ctypes.c_double(1.0), ctypes.c_double(0.0)
    routine(b"L", ctypes.byref(n), ctypes.byref(alpha), A.ctypes.data, ctypes.byref(n), x.ctypes.data,
            ctypes.byref(one), ctypes.byref(beta), y.ctypes.data, ctypes.byref(one))
    return y


def triangular_solve(U, v, transpose: bool = False):
    """U⁻¹ v (or U⁻ᵀ v) for an upper triangular U (n, n), Fortran order, float64 (the strict lower triangle
    is not read), v (n,) or (n, k): BLAS dtrsv or dtrsm, releasing the GIL."""
    import ctypes

    import numpy as np

    i, c = ctypes.POINTER(ctypes.c_int), ctypes.c_char_p
    p, d = ctypes.c_void_p, ctypes.POINTER(ctypes.c_double)
    block = np.ndim(v) == 2
    routine = (_nogil("cython_blas", "dtrsm", c, c, c, c, i, i, d, p, i, p, i) if block else
               _nogil("cython_blas", "dtrsv", c, c, c, i, p, i, p, i))
    if routine is None or not (U.flags.f_contiguous and U.dtype == np.float64):
        from scipy.linalg import blas, lapack

        if block:
            return lapack.dtrtrs(U, v, trans=int(transpose))[0]
        return blas.dtrsv(U, v, trans=int(transpose))
    x = np.array(v, dtype=np.float64, order="F")  # (a copy: the routines overwrite their right-hand side)
    n, one = ctypes.c_int(U.shape[0]), ctypes.c_int(1)
    trans = b"T" if transpose else b"N"
    if block:
        k, alpha = ctypes.c_int(x.shape[1]), ctypes.c_double(1.0)
        routine(b"L", b"U", trans, b"N", ctypes.byref(n), ctypes.byref(k), ctypes.byref(alpha), U.ctypes.data,
                ctypes.byref(n), x.ctypes.data, ctypes.byref(n))
    else:
        routine(b"U", trans, b"N", ctypes.byref(n), U.ctypes.data, ctypes.byref(n), x.ctypes.data,
                ctypes.byref(one))
    return x


def in_parallel(*calls, parallel: bool = True):
    """[call() for call in calls], the first in this thread and each other in a thread of its own: for numpy
    and scipy.sparse work that releases the GIL (sparse products: two halves on two cores take 0.55 of the
    time of one). The first exception raised is re-raised here. ``parallel`` False: one after the other
    here -- small work, where starting threads and sharing the caches cost more than a second core gains."""
    import threading

    if not parallel:
        return [call() for call in calls]
    results, errors = [None] * len(calls), []

    def run(i):
        try:
            results[i] = calls[i]()
        except BaseException as e:
            errors.append(e)

    threads = [threading.Thread(target=run, args=(i,), name="olti-parallel") for i in range(1, len(calls))]
    for t in threads:
        t.start()
    run(0)
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return results
