"""Executors: where the tasks of a tiled stage run.

:class:`LocalExecutor`: worker processes on this machine (``executor: {kind:
local, workers: N}``; one task, or one worker, runs in this process).
:class:`DaskExecutor`: a Dask cluster at ``executor.address``, or a local one
of ``workers`` processes (workers need this package and the cache folder at
the same path: a cluster's workers are checked on connecting, and a task
that cannot find a folder this run sees stops the run with one sentence,
:meth:`DaskExecutor.unseen`; a worker lost is logged, and a cluster left
without a worker for ``executor.no_workers_timeout_s`` stops the run,
:class:`_WorkerWatch`).  Tasks are module-level functions called with a small task
(paths and parameters, never large arrays) that return something small, in
task order; the transport is the executors' own, and nothing it serialises
is stored.  :func:`thread_map` runs a function on threads of this process
(for compiled code that releases the GIL), then hands the freed memory back.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import ctypes
import logging
import multiprocessing
import os
import signal
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from importlib import import_module
from multiprocessing import resource_tracker
from typing import Any

from pipeline import interrupt
from pipeline.cache import cache_root
from pipeline.errors import ConfigError, EnvironmentFailure
from pipeline.interrupt import sigint_held
from pipeline.log import LOGGER_NAME, hosting


class WorkerLost(EnvironmentFailure):
    """A worker process died under a task (exit code 4): killed, or out of memory.

    The runner sets :attr:`stage`, which the sentence then names first.
    """

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message
        self.stage: str | None = None

    def __str__(self) -> str:
        return f"stage '{self.stage}': {self.message}" if self.stage else self.message


#: What a worker's death is put down to, for the signals that usually cause it.
_CAUSES = {signal.SIGKILL: " — often the system's out-of-memory killer"}

#: Said after a worker's death: nothing is lost by running again.
_RESUME = "run again to resume: complete stages are reused."


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask, which a batch system sets)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def capped_workers(asked: int, log: Any = None) -> int:
    """*asked* worker processes, at most :func:`usable_cores`; a lowered number is logged once."""
    cores = usable_cores()
    if asked <= cores:
        return max(1, asked)
    if log is not None:
        log.info("executor.workers: %d asked, %d cores usable: using %d", asked, cores, cores)
    return cores


class LocalExecutor:
    """Worker processes on this machine (started once per run, on first use).

    At most :func:`usable_cores` of them, and never more than there are
    tasks to run.
    """

    def __init__(self, workers: int = 1):
        self.workers = max(1, min(int(workers), usable_cores()))
        self._pool: ProcessPoolExecutor | None = None

    def describe(self) -> str:
        return f"local, {self.workers} worker{'s' if self.workers > 1 else ''}"

    def prepare(self, fn: Callable[[Any], Any], tasks: int | None = None) -> None:
        """Start the workers and import *fn*'s module in each, while this process does other work.

        *tasks*, when known, bounds the number of workers started.
        """
        count = min(self.workers, tasks if tasks is not None else self.workers)
        if count <= 1:
            return
        _start_resource_tracker()
        with sigint_held():  # the workers start here and inherit the blocked mask
            if self._pool is None:
                self._pool = _pool(count)
            try:
                for _ in range(count):
                    self._pool.submit(import_module, fn.__module__)
            except BrokenProcessPool:
                pass  # a worker died already: map() says so

    def map(
        self,
        fn: Callable[[Any], Any],
        tasks: Sequence[Any],
        *,
        log: Any = None,
        what: str = "tiles",
        done: Callable[[Any], object] | None = None,
    ) -> list[Any]:
        """``[fn(t) for t in tasks]``, in parallel processes when there is more than one task.

        *done*, if given, is called here with each task as it finishes (a progress figure's update).
        """
        if self.workers == 1 or len(tasks) <= 1:
            results = []
            with contextlib.ExitStack() as quiet:
                if len(tasks) > 1:  # the tasks' own progress says nothing: the tasks done are the figure
                    quiet.enter_context(hosting(None))
                for i, t in enumerate(tasks):
                    results.append(fn(t))
                    _done(log, i + 1, len(tasks), what)
                    if done is not None:
                        done(t)
            return results
        try:
            _start_resource_tracker()
            with sigint_held():  # workers may start here and inherit the blocked mask
                if self._pool is None:
                    self._pool = _pool(min(self.workers, len(tasks)))
                futures = [self._pool.submit(_then_trim, fn, t) for t in tasks]
            completed = concurrent.futures.as_completed(futures)
            return _collect(futures, completed, log, what, lambda: [f.cancel() for f in futures], tasks, done)
        except BrokenProcessPool:
            if interrupt.received() is not None:  # the run is stopping: its signal, not the worker, says why
                raise interrupt.Interrupted(interrupt.received()) from None
            raise WorkerLost(f"a worker process died ({_death(self._pool)}); {_RESUME}") from None

    def close(self, abort: bool = False) -> None:
        """Stop the workers: after their tasks, or at once (``abort``: a failed or interrupted run).

        Aborting kills the workers (SIGKILL: they ignore SIGINT and SIGTERM,
        which only the run acts on) and waits for them to be gone, so no
        worker outlives the run and waiting never hangs on a busy one.
        """
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if not abort:
            pool.shutdown(wait=True, cancel_futures=True)
            return
        workers = list(getattr(pool, "_processes", {}).values())  # the pool's own record of its processes
        manager = getattr(pool, "_executor_manager_thread", None)
        for proc in workers:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                proc.kill()
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
                proc.join(5.0)
        # The pool's manager thread closes its wake-up pipe as it ends.  Python 3.11's exit hook writes to that
        # pipe without a lock (CPython added one in gh-125451, PR 125492): were the thread still ending at exit,
        # the write could meet the closed pipe and print a traceback (EBADF) after a Ctrl-C, as once in CI's
        # test_a_ctrl_c_of_the_group_while_workers_start_prints_no_traceback.  Waiting for the thread here
        # leaves the hook nothing to write to.
        if manager is not None:
            manager.join(5.0)


class DaskExecutor:
    """A Dask distributed cluster: the one at ``address``, or a local one started on first use."""

    def __init__(
        self,
        address: str | None = None,
        workers: int = 1,
        connect_timeout: float = 10.0,
        shared: Sequence[str | os.PathLike] = (),
        no_workers_timeout: float = 300.0,
    ):
        self.address = address
        self.workers = max(1, int(workers))
        #: Seconds to wait for the scheduler at ``address`` to answer.
        self.connect_timeout = float(connect_timeout)
        #: Folders every worker of the cluster at ``address`` must see as this run does (the cache).
        self.shared = [str(f) for f in shared]
        #: Seconds the cluster may have no worker while tasks wait (:class:`_WorkerWatch`).
        self.no_workers_timeout = float(no_workers_timeout)
        self._client = None
        self._cluster = None
        self._watch: _WorkerWatch | None = None

    def describe(self) -> str:
        return f"dask {self.address}" if self.address else f"dask local cluster, {self.workers} workers"

    def prepare(self, fn: Callable[[Any], Any], tasks: int | None = None) -> None:
        """Nothing to do ahead: a Dask cluster is connected to on first use."""

    def _connect(self):
        if self._client is not None:
            return self._client
        try:
            # lazy: Dask takes ~0.6 s to import, for executor kind dask only; every stage's process imports this module
            from distributed import Client, LocalCluster
        except ImportError:  # pragma: no cover - a dependency
            raise ConfigError(
                "executor.kind: dask needs the 'distributed' package (pip install distributed)."
            ) from None
        for name in ("distributed", "bokeh", "tornado"):
            logging.getLogger(name).setLevel(logging.ERROR)
        # a lost scheduler is logged there with a traceback; map() says it in one sentence
        logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
        if self.address:
            self._client = self._reach(lambda: Client(self.address, timeout=self.connect_timeout))
            try:
                for folder in self.shared:
                    self._check_shared(self._client, folder)
            except BaseException:
                self.close()
                raise
        else:
            self._cluster = LocalCluster(
                n_workers=self.workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            self._client = Client(self._cluster)
        client = self._client
        where = (
            f"executor.address {self.address}"
            if self.address
            else f"the local Dask cluster at {client.scheduler.address}"
        )
        self._watch = _WorkerWatch(lambda: _workers_now(client), self.no_workers_timeout, where, self.address)
        # the scheduler's cluster-wide events (workers added and removed, ...) go to the topic "all"
        client.subscribe_topic("all", self._watch.removed)
        return client

    def _reach(self, connect: Callable[[], Any]) -> Any:
        """``connect()``, given :attr:`connect_timeout` seconds to succeed, else ``EnvironmentFailure``.

        The client's own timeout covers the connection but not the scheduler's
        first message: something that accepts the connection and stays silent
        (not a scheduler, or a hung one) would be waited on for ever.  A TCP
        address is first probed (:func:`_speaks_first`), so that a client is
        made only where a scheduler answers; the attempt then runs on a thread
        of its own, abandoned when the time is up.
        """
        deadline = time.monotonic() + self.connect_timeout
        if not _speaks_first(self.address, deadline):
            raise self._silent()
        box: dict[str, Any] = {}

        def attempt() -> None:
            try:
                box["client"] = connect()
            except Exception as exc:  # handed to the waiting thread
                box["error"] = exc

        thread = threading.Thread(target=attempt, name="dask-connect", daemon=True)
        thread.start()
        thread.join(max(deadline - time.monotonic(), 0.0) + 0.5)
        error = box.get("error")
        if isinstance(error, ValueError):
            raise ConfigError(f"executor.address {self.address}: not a Dask address ({error}).") from None
        if thread.is_alive() or isinstance(error, (OSError, TimeoutError)):
            raise self._silent()
        if error is not None:
            raise error
        return box["client"]

    def _silent(self) -> EnvironmentFailure:
        return EnvironmentFailure(
            f"executor.address {self.address}: no Dask scheduler answered within {self.connect_timeout:g} s; "
            "start it (`dask scheduler`) or correct the address."
        )

    def _check_shared(self, client: Any, folder: str) -> None:
        """Raise :meth:`unseen` unless every worker connected now reads the probe this run writes in *folder*.

        The probe holds a random token: a worker that sees another folder at
        the same path (its own disk) does not read it, though the path exists.
        """
        token = uuid.uuid4().hex
        probe = os.path.join(folder, f".dask-probe-{token}")
        with open(probe, "w") as fh:
            fh.write(token)
        try:
            seen = client.run(_read_probe, probe)
        finally:
            with contextlib.suppress(OSError):
                os.remove(probe)
        blind = sorted(worker for worker, text in seen.items() if text != token)
        if blind:
            raise self.unseen(folder, blind[0])

    def unseen(self, folder: str, worker: str | None = None) -> EnvironmentFailure:
        """The sentence for a *folder* this run sees and a worker (named, or one) does not (exit 4)."""
        who = f"worker {worker} of {self.address}" if worker else f"a Dask worker of {self.address or 'the cluster'}"
        return EnvironmentFailure(
            f"{who} cannot see the folder {folder}, which this run sees: the cache and its workspaces "
            "must be on a filesystem every worker mounts at the same path."
        )

    def map(
        self,
        fn: Callable[[Any], Any],
        tasks: Sequence[Any],
        *,
        log: Any = None,
        what: str = "tiles",
        done: Callable[[Any], object] | None = None,
    ) -> list[Any]:
        """``[fn(t) for t in tasks]`` on the cluster's workers; *done* as :meth:`LocalExecutor.map`'s.

        A task that raises ``FileNotFoundError`` for a path that exists here
        ran on a worker that does not share this run's filesystem:
        :meth:`unseen` names the folder.  Tasks the scheduler cancels (it
        stopped, or the connection to it was lost), a task that killed
        every worker that tried it, and a cluster left without a worker for
        :attr:`no_workers_timeout` seconds (the tasks are cancelled) are
        ``EnvironmentFailure`` (exit 4); a worker lost is logged
        (:class:`_WorkerWatch`).  Other errors are the task's own.
        """
        if not tasks:
            return []
        # lazy: Dask takes ~0.6 s to import, for executor kind dask only; every stage's process imports this module
        import distributed

        client = self._connect()
        futures = client.map(fn, list(tasks), pure=False)
        try:
            completed = self._watch.completed(
                distributed.as_completed(futures, loop=client.loop), [f.key for f in futures], log
            )
            return _collect(futures, completed, log, what, lambda: client.cancel(futures), tasks, done)
        except WorkerLost:  # the cluster had no worker for too long: the scheduler forgets the tasks
            client.cancel(futures)
            raise
        except (FileNotFoundError, NotADirectoryError) as exc:
            path = exc.filename
            if not isinstance(path, str) or not os.path.exists(path):
                raise
            raise self.unseen(path if os.path.isdir(path) else os.path.dirname(path)) from None
        except concurrent.futures.CancelledError as exc:  # not ours: _collect raises the failure it cancels for
            where = f"executor.address {self.address}" if self.address else "the local Dask cluster"
            reason = getattr(exc, "reason", None) or "it stopped or the connection to it was lost"
            raise EnvironmentFailure(f"{where}: the Dask scheduler cancelled the tasks ({reason}); {_RESUME}") from None
        except distributed.KilledWorker:
            raise WorkerLost(
                "a Dask worker died running a task, on every worker that tried it (often the out-of-memory "
                f"killer); {_RESUME}"
            ) from None

    def close(self, abort: bool = False) -> None:
        """Disconnect (and stop a local cluster); ``abort`` is the same here: the scheduler cancels the tasks."""
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None


class _WorkerWatch:
    """A Dask cluster's workers while the run waits for its tasks: each one lost is logged, none for long fails.

    Parameters
    ----------
    count : callable
        The number of workers the scheduler has now, None when it cannot
        be asked (:func:`_workers_now`).
    timeout : float
        Seconds the cluster may have no worker while tasks wait
        (``executor.no_workers_timeout_s``).
    where : str
        The scheduler, as the failure's sentence names it.
    address : str or None
        The scheduler's address, for the advice to start workers; None for a
        local cluster, which starts its own.
    clock, sleep : callable
        ``time.monotonic`` and ``time.sleep``, replaced in tests.

    Notes
    -----
    The scheduler publishes a ``remove-worker`` event to its topic ``"all"``
    naming the worker, the keys it was running or had queued, and those
    whose results it held (which it computes again).  The client is
    subscribed to it (:meth:`removed`, on the client's event-loop thread);
    :meth:`completed` says each one in a WARNING line, from the run's
    thread.  The events carry exactly what is re-run, as the scheduler saw
    it; polling the workers' tasks instead would guess it between two
    polls.  The events do not say when the last worker is gone for good:
    while no task completes, the number of workers is asked once a second.
    """

    def __init__(
        self,
        count: Callable[[], int | None],
        timeout: float,
        where: str,
        address: str | None,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], Any] = time.sleep,
    ):
        self.count = count
        self.timeout = float(timeout)
        self.where = where
        self.address = address
        self.clock = clock
        self.sleep = sleep
        #: Seconds between two questions of the number of workers, while no task completes.
        self.every = min(1.0, self.timeout / 5)
        self._removed: collections.deque[dict] = collections.deque()  # appended on the client's thread

    def removed(self, event: tuple[float, Any]) -> None:
        """Keep a ``remove-worker`` event of the scheduler (``(time, message)``), for :meth:`completed` to say."""
        message = event[1] if isinstance(event, tuple | list) and len(event) == 2 else event
        if isinstance(message, dict) and message.get("action") == "remove-worker":
            self._removed.append(message)

    def completed(self, pending: Any, keys: Sequence[Any], log: Any = None) -> Iterator[Any]:
        """The futures of *pending* (a ``distributed.as_completed`` of the tasks *keys*) as they complete.

        Each worker lost meanwhile is one WARNING line on *log*.  Raises
        :class:`WorkerLost` when the cluster has had no worker for
        :attr:`timeout` seconds while tasks wait; the caller cancels them.
        """
        keys = set(keys)
        log = log if log is not None else logging.getLogger(LOGGER_NAME)
        asked = -float("inf")
        empty_since: float | None = None  # when the cluster was first seen without a worker
        while not pending.is_empty():
            self._say_removed(keys, log)
            ready = pending.next_batch(block=False)
            if ready:
                yield from ready
                continue
            now = self.clock()
            if now - asked >= self.every:
                asked = now
                workers = self.count()  # None: not known now, the clock runs on as it was
                if workers:
                    empty_since = None
                elif workers == 0 and empty_since is None:
                    empty_since = now
            if empty_since is not None and now - empty_since >= self.timeout:
                self._say_removed(keys, log)
                raise WorkerLost(self._none_for(pending.count(), len(keys)))
            self.sleep(min(0.1, self.every))

    def _say_removed(self, keys: set, log: Any) -> None:
        if not self._removed:
            return
        left = self.count()
        while self._removed:
            log.warning("%s", self._lost(self._removed.popleft(), keys, left))

    def _lost(self, message: dict, keys: set, left: int | None) -> str:
        """The line for the ``remove-worker`` *message*: the worker, and what of *keys* it had."""
        had = set(message.get("processing-tasks") or ()) | set(message.get("lost-computed-tasks") or ())
        held = len(had & keys)
        how = "was retired" if message.get("expected") else "was lost"
        line = f"Dask worker {message.get('worker', '?')} {how}; it had {held or 'none'} of the {len(keys)} tasks"
        if held:
            line += " (running, queued or done), " + ("to re-run" if left == 0 else "re-run on the other workers")
        if left == 0:
            line += f"; no worker is left: the run waits {self.timeout:g} s for one (executor.no_workers_timeout_s)"
        return line

    def _none_for(self, pending: int, total: int) -> str:
        start = f"start workers (`dask worker {self.address}`), then " if self.address else ""
        return (
            f"{self.where}: no Dask worker for {self.timeout:g} s (executor.no_workers_timeout_s) with {pending} of "
            f"the {total} tasks still to run; {start}{_RESUME}"
        )


def _workers_now(client: Any) -> int | None:
    """The number of workers of *client*'s scheduler; None while it cannot be asked.

    A scheduler just lost would be asked until the client's connect timeout
    ends; the client says it is lost first (its status), and the tasks are
    then cancelled (:meth:`DaskExecutor.map` says so).
    """
    if client.status != "running":
        return None
    try:
        return len(client.nthreads())
    except OSError:  # the connection was lost while asking
        return None


def _read_probe(path: str) -> str | None:
    """On a worker: the text of the file at *path*, None where it cannot be read."""
    try:
        with open(path) as fh:
            return fh.read()
    except OSError:
        return None


def _speaks_first(address: str, deadline: float) -> bool:
    """Whether the server at a TCP *address* sends its first bytes before *deadline* (``time.monotonic``).

    A Dask scheduler greets every connection (its handshake); a closed port,
    a name that does not resolve, or a listener that stays silent does not.
    Connecting is retried until the deadline (a scheduler may be starting).
    Addresses of other schemes (tls, ucx, ws) are not probed: True.  An
    address Dask cannot read is a ``ConfigError``.
    """
    # lazy: Dask takes ~0.6 s to import, for executor kind dask only; every stage's process imports this module
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme != "tcp":
            return True
        host, port = parse_host_port(location)
    except ValueError as exc:
        raise ConfigError(f"executor.address {address}: not a Dask address ({exc}).") from None
    while (left := deadline - time.monotonic()) > 0:
        try:
            with socket.create_connection((host, port), timeout=left) as sock:
                sock.settimeout(max(deadline - time.monotonic(), 0.01))
                if sock.recv(1):
                    return True
        except OSError:  # refused, unreachable, not resolved, or silent until the deadline
            pass
        time.sleep(min(0.2, max(deadline - time.monotonic(), 0.0)))
    return False


def thread_map(fn: Callable[[Any], Any], items: Sequence[Any], threads: int) -> list[Any]:
    """``[fn(item) for item in items]``, on up to *threads* threads of this process.

    Worth it where *fn* spends its time in compiled code that releases the
    interpreter lock (NumPy, SciPy's filters, PROJ).  Results come in the
    order of *items*.  Afterwards the memory the threads freed is handed
    back to the system (:func:`release_freed_memory`).
    """
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    with concurrent.futures.ThreadPoolExecutor(min(threads, len(items))) as pool:
        out = list(pool.map(fn, items))
    release_freed_memory()
    return out


def _then_trim(fn: Callable[[Any], Any], task: Any) -> Any:
    """``fn(task)`` in a worker, then what it freed given back (:func:`release_freed_memory`).

    The workers live through the run: without it, each held the pages of
    its largest task into the next stages (several hundred MB at 100 M
    points, 2026-12-04).
    """
    try:
        return fn(task)
    finally:
        release_freed_memory()


def release_freed_memory() -> None:
    """Give the memory this process has freed but still holds back to the system (glibc's ``malloc_trim``).

    glibc gives each thread its own allocation arena, and an arena keeps the
    pages of the arrays freed in it (arrays under 32 MB are not mapped on
    their own): after SMRF's grid filter on two threads, the run held 120 MB
    more than before through the whole of ``rasterize`` (37.5 M points,
    2026-12-03), enough to take the TIN job to 1.18 GB.  Does nothing where
    the C library has no ``malloc_trim`` (macOS, musl).
    """
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return
    trim(0)


def _death(pool: ProcessPoolExecutor | None) -> str:
    """How a worker of *pool* died: the signal that killed it, or its exit status."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for _ in range(50):  # the pool's own thread may be reaping the dead worker at this moment
        codes = [p.exitcode for p in processes if p.exitcode not in (None, 0)]
        if codes:
            return _exit_in_words(codes[0])
        time.sleep(0.01)
    return "its exit status is not known"


def _exit_in_words(code: int) -> str:
    """A process's exit code (negative: the signal that ended it) in words."""
    if code >= 0:
        return f"exited with status {code}"
    try:
        sig = signal.Signals(-code)
    except ValueError:
        return f"killed by signal {-code}"
    return f"killed by signal {-code}, {sig.name}{_CAUSES.get(sig, '')}"


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker now, before SIGINT is held for the workers' start.

    Started on the first worker's launch, it unblocks SIGINT in the thread
    that launches it when done (its own way of starting with the signal
    held): inside :func:`~pipeline.interrupt.sigint_held`, every worker
    launched after it then started with SIGINT open, and a Ctrl-C landing
    before its initializer ignored the signal printed a traceback.
    """
    resource_tracker.ensure_running()


def _pool(workers: int) -> ProcessPoolExecutor:
    # spawn: a clean interpreter per worker (fork would copy the parent's
    # threads and GDAL/PROJ state).
    return ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn"), initializer=_exit_with_parent, initargs=(os.getpid(),)
    )


def _exit_with_parent(parent: int) -> None:
    """In a worker: leave signals to the run, and exit as soon as the run is gone (even killed with SIGKILL).

    SIGINT (Ctrl-C reaches the whole process group) and SIGTERM (systemd
    signals the whole group) are ignored: the run that owns the workers
    stops them, so they never print a traceback or break the pool under it.
    A killed run cannot stop its workers; without the watch they would wait
    for work forever.  Polls the parent's pid once a second (POSIX).
    """
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(1)
            time.sleep(1.0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _done(log: Any, k: int, n: int, what: str) -> None:
    if log is not None and n > 1:
        log.info("%s: %d of %d done", what, k, n)


def _collect(
    futures: list,
    completed: Iterable,
    log: Any,
    what: str,
    cancel: Callable[[], Any],
    tasks: Sequence[Any] = (),
    done: Callable[[Any], object] | None = None,
) -> list[Any]:
    """Wait for every future (logging progress); the first failure cancels the rest and is raised.

    *completed* yields the *futures* as they complete (``concurrent.futures.as_completed``, or
    :meth:`_WorkerWatch.completed` over ``distributed``'s); *done* is called with the task of each
    (*tasks*, in the futures' order).
    """
    position = {id(f): i for i, f in enumerate(futures)}
    keyed = {getattr(f, "key", None): i for i, f in enumerate(futures)}  # distributed's futures, by their key
    for k, future in enumerate(completed, 1):
        exc = future.exception()
        if exc is not None:
            cancel()
            raise exc
        _done(log, k, len(futures), what)
        if done is not None:
            i = position.get(id(future))
            done(tasks[i if i is not None else keyed[future.key]])
    return [f.result() for f in futures]


def make_executor(config: Any) -> LocalExecutor | DaskExecutor:
    """The executor the configuration's ``executor`` block names.

    Processes on this machine are at most its usable cores
    (:func:`capped_workers`); a remote cluster's workers are its own, and
    must see the cache folder at the same path (checked on connecting).
    """
    ex = getattr(config, "executor", None)
    if ex is None:
        return LocalExecutor(1)
    log = logging.getLogger(LOGGER_NAME)
    if ex.kind == "dask":
        workers = ex.workers if ex.address else capped_workers(ex.workers, log)
        shared = [cache_root(config)] if ex.address and hasattr(config, "output") else []
        return DaskExecutor(
            ex.address,
            workers,
            getattr(ex, "connect_timeout_s", 10.0),
            shared,
            no_workers_timeout=getattr(ex, "no_workers_timeout_s", 300.0),
        )
    return LocalExecutor(capped_workers(ex.workers, log))
