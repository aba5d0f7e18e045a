"""Where the tasks of a tiled run go: Dask's local schedulers, or a ``distributed`` cluster
(docs/tiled.md, "Threads"; docs/DECISIONS.md, "Threads of the tasks that run at once")."""
import importlib
import os
import time

#: Dask's local schedulers, by the names ``client`` takes for them.
LOCAL_SCHEDULERS = ("threads", "processes", "sync")


def check_client(client, name="client "):
    """``client``, or TypeError (not a client) or ValueError (a name no scheduler has) naming
    what it takes; the messages call it ``name``."""
    if not (client is None or isinstance(client, str) or hasattr(client, "submit")):
        raise TypeError(f"client must be None, one of {LOCAL_SCHEDULERS}, a scheduler address "
                        f"or a distributed.Client; got {client!r}")
    if isinstance(client, str) and client not in LOCAL_SCHEDULERS and ":" not in client:
        # Neither a local scheduler nor an address (host:port, tcp://host:port).
        raise ValueError(f"{name}{client!r} is neither a local scheduler "
                         f"({', '.join(LOCAL_SCHEDULERS)}) nor a scheduler's address such as "
                         f"'tcp://host:8786'")
    return client


class Runner:
    """Runs each tile's task on the chosen scheduler and reports each finished tile.

    The tasks that run at once share the cores: on the local schedulers at most ``n_jobs``
    tasks at once with ``n_jobs // tasks`` threads each (``"sync"``: one task with all of
    them), on ``distributed`` each worker's cores split between its threads' tasks
    (:func:`_worker_threads`). ``threads`` records what the tasks took, for ``stats``.
    """

    def __init__(self, client, n_jobs, report):
        self.client = client
        self.n_jobs = n_jobs
        self.report = report
        self.own = None
        self.pool = None
        self.name = "threads" if client is None else (
            client if client in LOCAL_SCHEDULERS else "distributed")
        self.threads = None

    def __enter__(self):
        try:
            importlib.import_module("distributed" if self.name == "distributed" else "dask")
        except ImportError as err:
            raise ImportError("tiled runs need Dask: pip install 'pssd_fast[dask]' (or "
                              "'dask[distributed]')") from err
        if isinstance(self.client, str) and self.name == "distributed":
            import distributed

            self.own = self.client = distributed.Client(self.client)
        if self.name == "processes":
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # One pool for the whole run: Dask would start (and import the library in) fresh
            # processes for every round. Spawned: a fork of a process whose numba threads
            # already ran can crash.
            self.pool = ProcessPoolExecutor(self.n_jobs,
                                            mp_context=multiprocessing.get_context("spawn"))
        return self

    def __exit__(self, *exc):
        if self.own is not None:
            self.own.close()
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)

    def _record(self, at_once, per_task):
        """Keep the round of the most tasks at once (of those, the most threads a task took):
        the two numbers of one round, where a round of one task takes every thread."""
        before = self.threads or {"tasks_at_once": 0, "threads_per_task": 0}
        if (at_once, per_task) > (before["tasks_at_once"], before["threads_per_task"]):
            self.threads = {"tasks_at_once": at_once, "threads_per_task": per_task}

    def map(self, stage, iteration, iterations, func, argsets):
        """``func(*args, n_jobs)`` for each of ``argsets``, results in their order; each
        finished task reported as ``stage`` of iteration ``iteration`` (from 0) of
        ``iterations``."""
        total = len(argsets)
        done = [0, time.perf_counter()]

        def finished():
            # Each tile is reported as a stage: the time since the one before.
            now = time.perf_counter()
            done[0] += 1
            if self.report is not None:
                self.report(iteration + 1, iterations, f"{stage} {done[0]}/{total}",
                            now - done[1])
            done[1] = now

        if self.name == "distributed":
            import distributed

            slots = {address: worker["nthreads"]
                     for address, worker in self.client.scheduler_info()["workers"].items()}
            # A worker lost meanwhile is left out here; Dask reruns its tasks elsewhere.
            shares = self.client.run(_worker_threads, on_error="ignore")
            self._record(sum(slots.values()), max(shares.values(), default=1))
            futures = [self.client.submit(_on_worker, func, *args, pure=False)
                       for args in argsets]
            for _ in distributed.as_completed(futures):
                finished()
            return self.client.gather(futures)
        import dask
        from dask.callbacks import Callback

        class Tiles(Callback):
            def _posttask(self, key, value, dsk, state, worker_id):
                finished()

        at_once = 1 if self.name == "sync" else max(1, min(total, self.n_jobs))
        per_task = max(1, self.n_jobs // at_once)
        self._record(at_once, per_task)
        tasks = [dask.delayed(func, pure=False)(*args, per_task) for args in argsets]
        pool = {} if self.pool is None else {"pool": self.pool}
        with Tiles():
            return list(dask.compute(*tasks, scheduler=self.name, num_workers=at_once, **pool))


def _worker_threads(dask_worker=None):
    """The threads of each task on a Dask worker (this task's, or ``dask_worker``, as
    ``Client.run`` passes it): the cores its process may use, shared between the tasks it runs
    at once (its ``nthreads``)."""
    if dask_worker is None:
        import distributed

        dask_worker = distributed.get_worker()
    cores = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
             else os.cpu_count() or 1)
    return max(1, cores // max(1, dask_worker.state.nthreads))


def _on_worker(func, *args):
    """``func(*args, n_jobs)`` with the worker's share of threads."""
    return func(*args, _worker_threads())
