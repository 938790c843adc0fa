"""olti_drake.threads: BLAS thread control, the GIL-releasing BLAS/LAPACK calls and in_parallel.

The ctypes calls must give scipy's own results (they call the same LAPACK), fall back to scipy's wrappers when
the function pointers are not available, and let another Python thread run while they compute.
"""

import threading
import time

import numpy as np
import pytest
from scipy.linalg import blas, lapack

from olti_drake import threads


@pytest.fixture(params=["ctypes", "f2py"])
def route(request, monkeypatch):
    """Both routes: the cython_lapack pointers through ctypes, and scipy's wrappers (no pointers found)."""
    if request.param == "f2py":
        monkeypatch.setattr(threads, "_NOGIL", {k: None for k in ("strtri", "dtrtri", "dsymv", "dtrsv")})
    return request.param


def _upper(n, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    U = np.asfortranarray(np.linalg.cholesky(A @ A.T / n + np.eye(n)).T)
    U[np.tril_indices(n, -1)] = rng.normal(size=n * (n - 1) // 2)  # garbage below: never read
    return U, rng


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_triangular_inverse_equals_lapack_and_leaves_the_lower_triangle(route, dtype):
    U, _ = _upper(60)
    inv, info = threads.triangular_inverse(U, dtype)
    ref, _ = (lapack.strtri if dtype == np.float32 else lapack.dtrtri)(np.asfortranarray(U, dtype=dtype), lower=0)
    assert info == 0 and inv.dtype == dtype and inv.flags.f_contiguous
    assert np.array_equal(np.triu(inv), np.triu(ref))
    assert np.array_equal(np.tril(inv, -1), np.tril(U, -1).astype(dtype))  # untouched
    tol = 1e-5 if dtype == np.float32 else 1e-12
    assert np.abs(np.triu(inv).astype(float) @ np.triu(U) - np.eye(60)).max() < tol


def test_symmetric_times_and_triangular_solve_equal_their_dense_definitions(route):
    U, rng = _upper(50)
    v = rng.normal(size=50)
    lower = np.tril(U)
    S = lower + lower.T - np.diag(np.diag(U))
    assert np.abs(threads.symmetric_times(U, v) - S @ v).max() < 1e-12
    T = np.triu(U)
    for transpose, A in ((False, T), (True, T.T)):
        x = threads.triangular_solve(U, v, transpose=transpose)
        assert np.abs(A @ x - v).max() < 1e-12
    assert np.array_equal(threads.triangular_solve(U, v), blas.dtrsv(U, v))  # the same BLAS routine
    V = rng.normal(size=(50, 4))
    V0 = V.copy()
    for transpose, A in ((False, T), (True, T.T)):  # a block of right-hand sides (dtrsm)
        X = threads.triangular_solve(U, V, transpose=transpose)
        assert X.shape == V.shape and np.abs(A @ X - V).max() < 1e-12
        assert np.abs(X - lapack.dtrtrs(U, V, trans=int(transpose))[0]).max() < 1e-12
    assert np.array_equal(V, V0)  # the right-hand sides are not overwritten


def test_the_ctypes_route_lets_another_thread_run_during_the_call():
    """While a triangular inverse of 2000 x 2000 runs in a helper, this thread's Python loop goes on (an f2py
    wrapper holding the GIL freezes it for the call's whole duration)."""
    if threads._nogil("cython_lapack", "dtrtri") is None:
        pytest.skip("scipy exposes no cython_lapack pointers here: the f2py route serves")
    U, _ = _upper(2000)

    def stalled() -> bool:
        done, spins = threading.Event(), []
        t = threading.Thread(target=lambda: (threads.triangular_inverse(U, np.float64), done.set()))
        t.start()
        while not done.is_set():
            spins.append(time.perf_counter())
        t.join()
        # The interpreter hands the GIL over every 5 ms at most while both want it: no stall of a whole inverse.
        return len(spins) < 100 or np.diff(spins).max() > 0.5 * (spins[-1] - spins[0])

    assert not all(stalled() for _ in range(3))  # (3 tries: a loaded machine may pause this thread once)


def test_in_parallel_returns_in_order_and_reraises():
    assert threads.in_parallel(lambda: 1, lambda: np.arange(3).sum(), lambda: "c") == [1, 3, "c"]

    def boom():
        raise ValueError("in a thread")

    with pytest.raises(ValueError, match="in a thread"):
        threads.in_parallel(lambda: 1, boom)


@pytest.mark.parametrize("parallel", [True, False])
def test_in_parallel_runs_small_work_here(parallel):
    """parallel=False: every call in this thread, one after the other (the same results)."""
    import threading

    names = threads.in_parallel(*[lambda: threading.current_thread().name] * 3, parallel=parallel)
    here = threading.current_thread().name
    assert names[0] == here and (names[1:] == [here, here]) != parallel


def test_blas_threads_set_and_restore():
    controls = threads._openblas_controls()
    if not controls:
        pytest.skip("no OpenBLAS found in this process")
    before = [get() for get, _ in controls]
    with threads.single_thread_blas():
        assert all(get() == 1 for get, _ in controls)
        with threads.blas_threads():
            assert [get() for get, _ in controls] == threads._STARTED
        assert all(get() == 1 for get, _ in controls)
    assert [get() for get, _ in controls] == before
