"""Seeded trials on many cores, and beyond one machine: the one entry point of the Monte Carlo (issue 26).

:func:`run_trials` runs ``n`` trials of a :class:`TrialTask` -- a picklable recipe: ``build(spec)`` once per worker
process (a Drake plant, an identification's measurement: things that do not travel between processes are rebuilt
from what does), then ``run(built, seed, arg)`` per trial -- on joblib:

* ``workers=1``: in this process, no pickling, no joblib;
* ``backend="loky"`` (default): joblib's worker processes on this machine (reused between calls);
* ``backend="dask"``: joblib's Dask backend on a ``distributed`` cluster -- a local one of ``workers``
  single-threaded worker processes, or the scheduler at ``scheduler`` (``tcp://host:8786``; or a
  ``distributed.Client``);
* ``backend="ray"``: joblib's Ray backend (``ray.util.joblib``) on the Ray cluster ``ray.init`` finds
  (``RAY_ADDRESS``) or a local one.

Every trial has its own seed, ``numpy.random.SeedSequence(seed).spawn(n)``, and the results come back in trial
order: they are the same, bit for bit on one machine, for any backend, worker count and ``batch`` (trials per
dispatch). Workers run BLAS on one thread (they already fill the cores).
"""

import contextlib
import hashlib
import os
from typing import Callable, Optional, Sequence

import numpy as np

from olti_drake.errors import InputError
from olti_drake.threads import single_thread_blas

BACKENDS = ("loky", "dask", "ray")
#: Default worker count: up to this many cores (the machines this runs on are shared).
DEFAULT_WORKERS = 2
#: Built objects a worker process keeps (by task key): a long-lived Dask worker serves many tasks.
KEEP_BUILT = 4
_NEEDS = {"dask": ("dask[distributed]", "olti_drake[cluster]"), "ray": ("ray", "ray")}


class TrialTask:
    """What the trials run: ``build(spec)`` once per worker process, then ``run(built, seed, arg)`` per trial
    (``seed`` a :class:`numpy.random.SeedSequence`). ``build`` and ``run`` are module-level functions; ``spec``
    is pickled (cloudpickle) only when the trials leave this process, and a worker builds each spec once
    (keyed by the digest of its pickle). ``local``: the object ``build(spec)`` would give, already built here
    (``workers=1`` uses it as is)."""

    def __init__(self, build: Callable, spec, run: Callable, local=None):
        self.build, self.spec, self.run, self.local = build, spec, run, local
        self._portable = None

    def built_here(self):
        if self.local is None:
            self.local = self.build(self.spec)
        return self.local

    def portable(self) -> tuple:
        """(build, run, key, pickled spec): what travels to the workers; ValueError naming what does not pickle."""
        if self._portable is None:
            import cloudpickle

            try:
                payload = cloudpickle.dumps(self.spec)
            except Exception as e:  # (pybind objects raise TypeError; others RuntimeError, PicklingError)
                why = str(e).splitlines()[0] if str(e) else type(e).__name__
                raise InputError(f"the trials cannot leave this process: {type(self.spec).__name__} does not pickle "
                                 f"({why}); use --workers 1") from None
            self._portable = (self.build, self.run, hashlib.sha256(payload).hexdigest(), payload)
        return self._portable


# In a worker process: key -> built object (a plain dict: loky and Dask keep their workers between calls).
_BUILT = {}


def _built(build, key, payload):
    if key not in _BUILT:
        import pickle

        while len(_BUILT) >= KEEP_BUILT:
            _BUILT.pop(next(iter(_BUILT)))
        _BUILT[key] = build(pickle.loads(payload))
    return _BUILT[key]


def _trial(portable, seed, arg):
    """One trial in a worker: the built object (once per process), the trial's seed, BLAS on one thread."""
    build, run, key, payload = portable
    with single_thread_blas():
        return run(_built(build, key, payload), seed, arg)


def check_backend(backend: str, scheduler=None, workers: Optional[int] = None) -> None:
    """Refuse, in one line, a backend that is not known or whose package is not installed, a scheduler given for
    a backend that takes none, and a worker count given with a scheduler (its cluster has its own)."""
    import importlib.util

    if backend not in BACKENDS:
        raise InputError(f"--backend {backend}: not one of {', '.join(BACKENDS)}")
    if scheduler is not None and backend != "dask":
        raise InputError(f"--scheduler applies to --backend dask (Ray finds its cluster from RAY_ADDRESS), "
                         f"not --backend {backend}")
    if scheduler is not None and workers is not None:
        raise InputError(f"--workers {workers}: the cluster of --scheduler {scheduler} has its own workers "
                         f"(drop --workers)")
    if backend in _NEEDS and importlib.util.find_spec("distributed" if backend == "dask" else backend) is None:
        package, extra = _NEEDS[backend]
        raise InputError(f"--backend {backend} needs the '{package}' package: pip install {extra}")


def effective_workers(workers: Optional[int]) -> int:
    """The worker count of ``workers`` (None: up to :data:`DEFAULT_WORKERS` cores of this machine)."""
    return min(os.cpu_count() or 1, DEFAULT_WORKERS) if workers is None else max(1, int(workers))


def run_trials(task: TrialTask, n: int, seed=0, workers: Optional[int] = None, backend: str = "loky",
               scheduler=None, batch: int = 1, args: Optional[Sequence] = None,
               progress: Optional[Callable[[int, object], None]] = None) -> list:
    """[run(built, seed_i, args[i]) for i < n] in trial order, on ``workers`` processes of ``backend``.

    ``seed``: an int, or a :class:`numpy.random.SeedSequence` whose next ``n`` children are taken (successive
    calls on one sequence continue it: adaptive rounds). ``args``: one argument per trial (default None each).
    ``batch``: trials per dispatch to a worker (many short trials: larger). ``progress(i, result)`` when the
    i-th trial (1-based) is back. ``workers=1`` with ``backend="loky"`` runs here; any other case sends the task
    to worker processes (:meth:`TrialTask.portable`).
    """
    check_backend(backend, scheduler)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    seeds = root.spawn(int(n))
    args = [None] * len(seeds) if args is None else list(args)
    if len(args) != len(seeds):
        raise ValueError(f"run_trials: {len(args)} arguments for {len(seeds)} trials")
    workers = effective_workers(workers)
    if backend == "loky":  # no more processes than trials (one trial: here, no workers to start)
        workers = min(workers, max(1, len(seeds)))
    if workers == 1 and backend == "loky":
        built = task.built_here()
        with single_thread_blas():  # the same arithmetic as in a worker
            results = (task.run(built, s, a) for s, a in zip(seeds, args))
            return _collect(results, progress)
    portable = task.portable()
    calls = [(portable, s, a) for s, a in zip(seeds, args)]
    with _backend(backend, workers, scheduler) as n_jobs:
        from joblib import Parallel, delayed

        # (Ray's joblib backend returns lists only: its progress comes at the end.)
        parallel = Parallel(n_jobs=n_jobs, batch_size=batch, return_as="list" if backend == "ray" else "generator",
                            max_nbytes=None)
        return _collect(parallel(delayed(_trial)(*c) for c in calls), progress)


def _collect(results, progress) -> list:
    out = []
    for r in results:
        out.append(r)
        if progress:
            progress(len(out), r)
    return out


@contextlib.contextmanager
def _backend(backend: str, workers: int, scheduler):
    """joblib's ``backend`` configured for ``workers`` (a local Dask cluster made and closed here when no
    scheduler is given); yields the n_jobs to ask for."""
    from joblib import parallel_config

    with contextlib.ExitStack() as stack:
        if backend == "loky":
            # The workers ask the kernel to end them with this process (a kill -9 of olti leaves none behind).
            stack.enter_context(parallel_config(backend="loky", initializer=die_with_parent, initargs=(os.getpid(),)))
            yield workers
        elif backend == "dask":
            stack.enter_context(parallel_config(backend="dask", client=_dask_client(stack, workers, scheduler)))
            yield -1  # every worker of the cluster
        else:
            from ray.util.joblib import register_ray

            register_ray()
            stack.enter_context(parallel_config(backend="ray"))
            yield workers


def _dask_client(stack, workers: int, scheduler):
    """The ``distributed.Client`` of ``scheduler``: the caller's own Client as is, an address connected to, or
    None -- a local cluster of ``workers`` processes of one thread each (the trials hold the GIL)."""
    from distributed import Client, LocalCluster

    if scheduler is not None and not isinstance(scheduler, str):
        return scheduler
    if scheduler:
        return stack.enter_context(Client(scheduler, set_as_default=False))
    cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                               dashboard_address=None))
    return stack.enter_context(Client(cluster, set_as_default=False))


def die_with_parent(parent_pid: int) -> None:
    """A worker's first act: ask the kernel to end it when its parent dies (Linux ``PR_SET_PDEATHSIG``), so that
    ``kill -9`` of ``olti uncertainty`` leaves no worker running its trials on the cores; if the parent is already
    gone (it died before this ran), end now."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # (not Linux: no such call; the executor's own shutdown still applies)
        pass
    if os.getppid() != parent_pid:
        os._exit(1)
