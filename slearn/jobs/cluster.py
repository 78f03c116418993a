"""Running slearn's tasks on Ray: the session, the tasks' errors, and their progress.

Ray is optional (``pip install 'slearn[ray]'``). ``--workers N`` starts a Ray instance of
N CPUs on this machine for the job and stops it after; ``--ray ADDRESS`` (or ``auto``)
joins a running cluster (``ray start --head`` on one machine, ``ray start
--address=HEAD:6379`` on the others) and leaves it running. A process that already has
Ray initialised (a notebook, the tests) keeps its own instance.

Tasks read logs by path: every node must see the logs at the same path (a shared
filesystem: NFS, a cluster filesystem, a bucket mounted at the same place) and have the
same slearn installed. What travels between tasks is plain data: paths, JSON-able dicts
and library files' bytes (the format of :mod:`slearn.io.library_file`), never slearn objects.

A task whose worker process died (killed, out of memory, a node lost) is run again by
Ray, up to ``MAX_RETRIES`` times; tasks are pure functions of their inputs, so a retried
task gives the same result. An error a task raises on purpose (a bad log) is not retried:
it stops the job and is raised in the driver as it was raised in the task.
"""

from __future__ import annotations

import os
import signal
import socket
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

from slearn.errors import InputError, SlearnError
from slearn.io.library_file import LoadedLibrary, load_library, save_library

INSTALL = "pip install 'slearn[ray]'"
MAX_RETRIES = 3
"""Times Ray runs a task again after its worker process died."""

_WAIT_S = 1.0  # longest wait between progress lines
_CONNECT_S = 10.0


class ClusterError(SlearnError):
    """The cluster could not be reached, or a task's worker died more than ``MAX_RETRIES`` times."""


def require_ray():
    """The ``ray`` module.

    Raises:
        InputError: Ray is not installed (the message says what to install).
    """
    try:
        import ray
    except ImportError:
        raise InputError(f"--workers and --ray need Ray, which is not installed: {INSTALL}") from None
    return ray


@contextmanager
def ray_session(workers: int | None = None, address: str | None = None) -> Iterator[Any]:
    """Ray, initialised for a job: ``workers`` CPUs on this machine, or the cluster at
    ``address`` (``"auto"``: the one started on this machine by ``ray start``).

    Raises:
        InputError: Ray is not installed, or neither or both of ``workers`` and ``address``.
        ClusterError: the cluster at ``address`` cannot be reached.
    """
    ray = require_ray()
    if (workers is None) == (address is None):
        raise InputError("give --workers N (Ray on this machine) or --ray ADDRESS (a cluster), not both")
    if ray.is_initialized():  # the caller's own instance: leave it as it is
        yield ray
        return
    options = dict(include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    if address is not None:
        _check_reachable(address)
    handlers = _own_signal_handlers()
    try:
        if address is not None:
            ray.init(address=address, **options)
        else:
            ray.init(num_cpus=workers, **options)
    except (ConnectionError, RuntimeError, ValueError) as err:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise ClusterError(f"cannot start or join {where}: {str(err).splitlines()[0] if str(err) else err!r} "
                           f"(start one with `ray start --head`)") from None
    finally:
        for signum, handler in handlers.items():  # ray.init replaced them
            signal.signal(signum, handler)
    try:
        yield ray
    finally:
        ray.shutdown()


def _own_signal_handlers() -> dict[int, Callable]:
    """The Python handlers of SIGTERM and SIGHUP (``slearn``'s command line installs them
    so that a stopped job removes its temporary files): ``ray.init`` replaces them with its
    own, which prints a C stack trace and exits, so they are put back after it."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGHUP)}
    return {signum: handler for signum, handler in handlers.items() if callable(handler)}


def _check_reachable(address: str) -> None:
    """Refuse a ``host:port`` nobody listens on at once (Ray itself retries for minutes)."""
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return  # "auto", "ray://...": Ray's own lookup
    try:
        socket.create_connection((host, int(port)), timeout=_CONNECT_S).close()
    except OSError as err:
        raise ClusterError(f"cannot join the Ray cluster at {address}: {err.strerror or err} "
                           f"(start one with `ray start --head`, and give its address)") from None


def check_visible(path: str) -> None:
    """Refuse a log this node cannot see (run inside a task).

    Raises:
        InputError: ``path`` does not exist here, naming the node.
    """
    if not os.path.exists(path):
        raise InputError(f"{path}: not found on node {socket.gethostname()}: Ray workers read logs "
                         f"by path, so every node must see them at the same path (a shared filesystem)")


def library_bytes(save: Callable[[Path], object]) -> bytes:
    """The bytes of a library file that ``save(path)`` writes (to a temporary folder)."""
    with tempfile.TemporaryDirectory(prefix="slearn-") as folder:
        path = Path(folder) / "library.parquet"
        save(path)
        return path.read_bytes()


def library_from_bytes(data: bytes) -> LoadedLibrary:
    """The library a file of ``data`` holds (read through :func:`load_library`)."""
    with tempfile.TemporaryDirectory(prefix="slearn-") as folder:
        path = Path(folder) / "library.parquet"
        path.write_bytes(data)
        loaded = load_library(path)
    loaded.path = None
    return loaded


def loaded_bytes(loaded: LoadedLibrary) -> bytes:
    """The bytes of ``loaded`` saved as a library file."""
    return library_bytes(lambda path: save_library(
        path, loaded.library, loaded.vocabulary, spec=loaded.spec, params=loaded.params,
        provenance=loaded.provenance))


def gather(ray, refs: list, names: list[str], on_done: Callable[[int, Any], None] | None = None) -> list:
    """The results of ``refs`` in order, calling ``on_done(i, result)`` as each arrives.

    Raises:
        SlearnError: the first error a task raised on purpose, as it was raised (the other
            tasks are cancelled).
        ClusterError: a task's worker died more than ``MAX_RETRIES`` times.
    """
    results: list = [None] * len(refs)
    index = {ref: i for i, ref in enumerate(refs)}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1, timeout=_WAIT_S)
            for ref in done:
                i = index[ref]
                results[i] = _get(ray, ref, names[i])
                if on_done is not None:
                    on_done(i, results[i])
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    return results


def streamed(ray, stream, name: str) -> Iterator[Any]:
    """The values a Ray generator task yields, in order, as they arrive (``stream`` is its
    ``ObjectRefGenerator``); errors as :func:`gather` raises them.

    Raises:
        SlearnError: the error the task raised on purpose, as it was raised.
        ClusterError: the task's worker died more than ``MAX_RETRIES`` times.
    """
    try:
        for ref in stream:
            yield _get(ray, ref, name)
    except _died(ray) as err:  # iterating found the task dead
        raise _worker_died(name, err) from None


def _get(ray, ref, name: str):
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as err:
        if isinstance(err.cause, SlearnError):
            raise err.cause from None
        raise
    except _died(ray) as err:
        raise _worker_died(name, err) from None


def _died(ray) -> tuple:
    """Ray's errors for a task whose worker (or node, or result) was lost for good."""
    return ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError, ray.exceptions.ObjectLostError


def _worker_died(name: str, err: BaseException) -> ClusterError:
    return ClusterError(f"{name}: a Ray worker died {MAX_RETRIES + 1} times on this task "
                        f"({type(err).__name__}); see the Ray logs (/tmp/ray/session_latest/logs)")


class Rate:
    """Progress of a job on stderr: tasks done of all, and events per second."""

    def __init__(self, what: str, total: int, echo: Callable[[str], None] | None) -> None:
        self.what, self.total, self.echo = what, total, echo
        self.done, self.events, self.started = 0, 0, time.perf_counter()

    def add(self, events: int) -> None:
        """One more task done, with its events."""
        self.done += 1
        self.events += events
        if self.echo is not None:
            seconds = max(time.perf_counter() - self.started, 1e-9)
            self.echo(f"{self.what} {self.done}/{self.total} logs: {self.events:,} events, "
                      f"{self.events / seconds:,.0f} events/s")
