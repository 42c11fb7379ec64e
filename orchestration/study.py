"""Studies: many independent scenario runs on a ``concurrent.futures`` executor.

A study (Monte Carlo over seeds, robustness cases, tuning) is a list of jobs, each a picklable
call such as ``simulate(scenario, overrides)``. :func:`open_executor` gives the executor they run
on: local processes by default, or a Dask ``distributed`` cluster when a scheduler address is
given (``"local"`` starts a ``LocalCluster`` on this machine). :func:`map_jobs` runs the jobs with
a progress bar and returns their results in job order, so a study's numbers do not depend on the
executor or the number of workers.

Nothing finished is lost: within a :class:`StudyFolder` (the ``--out`` of ``flexfusion study``),
:func:`map_jobs` stores each job's result as it completes and ``--resume`` takes them back; a
lost local worker costs only the jobs it was running, and SIGINT/SIGTERM leave status
``interrupted`` with every finished job on disk.

Worker processes are forked from a clean server process (``forkserver``), not from this one
(which may hold threads and loaded FMUs), and live as long as the executor; each run frees its
FMU instances and unloads their libraries. (Replacing workers with ``max_tasks_per_child``
deadlocks Python 3.11's ``ProcessPoolExecutor`` when jobs are queued, python/cpython#115634.)
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import hmac
import json
import multiprocessing
import os
import pickle
import signal
import sys
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .results import Result
from .safe_io import FolderLock, FolderLockedError, atomic_write_bytes, atomic_write_json

if TYPE_CHECKING:
    from .scenario import Overrides


class StudyError(RuntimeError):
    """A study that could not be done as asked; ``results`` holds what the jobs that succeeded
    returned (``None`` for the failed ones)."""

    def __init__(self, message: str, results: list[Any] | None = None) -> None:
        super().__init__(message)
        self.results = results


# ---------------------------------------------------------------------------------------------
# one job: a scenario run kept in memory
# ---------------------------------------------------------------------------------------------
#: The former name of the in-memory result: a run is one :class:`~orchestration.results.Result`
#: whether it went to a folder or stayed in memory (``out_dir`` None).
RunArrays = Result


def simulate(scenario: str | Path | dict[str, Any], overrides: Overrides = (),
             variables: Sequence[str] | None = None) -> Result:
    """Run a scenario in memory (no files) and return its recorded signals and metrics as a
    :class:`~orchestration.results.Result` with no ``out_dir`` and the stepping's ``wall_time``:
    the run path of :func:`orchestration.master.run` (:func:`~orchestration.master.run_loaded`)
    without a folder.

    Parameters
    ----------
    scenario
        A scenario file or a parsed TOML document.
    overrides
        ``comp.param=value`` and ``scenario.seed=N`` strings, or a mapping
        ``{("ekf", "stiffness_scale"): 0.5}`` (see :mod:`orchestration.scenario`).
    variables
        Keep only these recorded variables (``comp.var``); default all.

    Raises
    ------
    ScenarioError, RunError
        As :func:`orchestration.master.run`.
    """
    from .master import load, run_loaded
    from .scenario import ScenarioError

    sc = load(scenario, overrides)
    missing = unrecorded(sc, variables or ())
    if missing:                                  # before the run, not after it
        raise ScenarioError(f"{sc.name}: not recorded: {', '.join(missing)}")
    run = run_loaded(sc)
    if variables is not None:
        keep = [i for i, c in enumerate(run.columns) if c.split("[", 1)[0] in set(variables)]
        run.columns = [run.columns[i] for i in keep]
        run.data = run.data[:, keep]
    return run


def simulate_recorded(scenario: str | Path | dict[str, Any], overrides: Overrides, variables: Sequence[str]
                      ) -> dict[str, Any]:
    """:func:`simulate` as a study's job result: ``{"time", "wall_time", variable: values}``
    (the form :func:`orchestration.batched.run_recorded` gives a run on the batched engine in)."""
    r = simulate(scenario, overrides, variables)
    return {"time": r.time, "wall_time": r.wall_time, **{v: r[v] for v in variables}}


def unrecorded(sc: Any, variables: Iterable[str]) -> list[str]:
    """The whole variables (``comp.var``) among ``variables`` that the loaded scenario ``sc``
    does not record, sorted."""
    have = {c.split("[", 1)[0] for c in sc.record_columns()}
    return sorted(set(variables) - have)


def require_recorded(sc: Any, variables: Iterable[str], purpose: str) -> None:
    """:class:`StudyError` naming what ``purpose`` (e.g. "the Monte Carlo study") needs and the
    scenario does not record: checked before any job runs, so that none runs in vain."""
    missing = unrecorded(sc, variables)
    if missing:
        raise StudyError(f"scenario '{sc.name}' does not record what {purpose} needs: "
                         f"{', '.join(missing)} (add them to [record] variables)")


# ---------------------------------------------------------------------------------------------
# executors
# ---------------------------------------------------------------------------------------------
@contextmanager
def open_executor(workers: int | None = None, scheduler: str | None = None,
                  connect_timeout: float = 10.0) -> Iterator[Executor]:
    """A ``concurrent.futures`` executor for a study's jobs.

    Parameters
    ----------
    workers
        Number of local worker processes (default: the machine's cores). With
        ``scheduler="local"``, the number of workers of the Dask ``LocalCluster``.
    scheduler
        ``None``: a local process pool (:class:`ProcessPool`, which :func:`map_jobs` restarts
        when a worker dies). An address (``tcp://host:8786``): the executor of a Dask
        ``distributed`` client connected to that scheduler. ``"local"``: a Dask
        ``LocalCluster`` started here (one thread per worker process).
    connect_timeout
        Seconds to wait for a remote scheduler.
    """
    if workers is not None and workers < 1:
        raise StudyError(f"--workers must be at least 1, not {workers}")
    if scheduler is None:
        pool = ProcessPool(workers or os.cpu_count() or 1)
        try:
            yield pool
        except BaseException:
            pool.terminate()      # an interrupt or an error: do not wait for the running jobs
            raise
        finally:
            pool.shutdown()
        return
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise StudyError("a Dask scheduler needs the packages 'dask' and 'distributed' "
                         "(pip install 'flexfusion[dask]')") from None
    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        if scheduler == "local":
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
            client = Client(cluster)
            client.run(_set_environment, _flexfusion_environment())
        else:
            cluster = None
            client = _connect(scheduler, connect_timeout)
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def _connect(address: str, timeout: float) -> Any:
    """A Dask client of the scheduler at ``address``, or :class:`StudyError` within ``timeout``.

    The scheduler is asked who it is first, under a deadline: ``Client`` alone waits forever on
    a service that accepts the connection and stays silent, and fails with odd errors (a
    ``MemoryError`` for an HTTP server's reply) on one that answers something else.
    """
    import asyncio

    from distributed import Client
    try:
        reply = asyncio.run(asyncio.wait_for(_identity(address, timeout), 2 * timeout))
    except TimeoutError:        # connected (within ``timeout``), then no answer
        raise StudyError(f"no Dask scheduler answered at {address} within {2 * timeout:g} s") from None
    except (OSError, ValueError, TypeError) as exc:            # no such host, port, scheme
        cause = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise StudyError(f"cannot reach the Dask scheduler at {address}: {cause}") from None
    except Exception as exc:  # noqa: BLE001 - what another protocol's reply makes Dask's raise
        raise StudyError(f"the service at {address} does not answer as a Dask scheduler "
                         f"({type(exc).__name__})") from None
    if not (isinstance(reply, dict) and reply.get("type") == "Scheduler"):
        raise StudyError(f"the service at {address} is not a Dask scheduler")
    return Client(address, timeout=timeout)


async def _identity(address: str, timeout: float) -> Any:
    from distributed.comm import connect
    comm = await connect(address, timeout=timeout)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


class ProcessPool(Executor):
    """A ``ProcessPoolExecutor`` on ``forkserver`` workers that can be restarted after one of
    its workers died (``BrokenProcessPool`` breaks a pool for good) and terminated at once.

    The fork server may be older than this process's settings: the ``FLEXFUSION_*`` environment
    is passed on. Workers ignore SIGINT: a Ctrl-C reaches the whole process group, and it is
    this process that ends the study (and terminates them).

    Its workers are found through public APIs (``ProcessPoolExecutor`` has no way to end them
    before Python 3.14's ``terminate_workers``): the children of this process that
    ``multiprocessing.active_children`` lists and that were not there when the pool was made;
    the study process starts no other processes while its pool lives.
    """

    def __init__(self, workers: int) -> None:
        self.max_workers = workers
        self._pool = self._new()

    def _new(self) -> ProcessPoolExecutor:
        self._before = {p.pid for p in multiprocessing.active_children()}    # not the pool's
        return ProcessPoolExecutor(max_workers=self.max_workers,
                                   mp_context=multiprocessing.get_context("forkserver"),
                                   initializer=_init_worker, initargs=(_flexfusion_environment(),))

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        return self._pool.submit(fn, *args, **kwargs)

    def restart(self) -> None:
        """A fresh pool in place of a broken one."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = self._new()

    def terminate(self) -> None:
        """Kill the workers (their running jobs are lost) and cancel the queued jobs."""
        for proc in self.workers():
            proc.terminate()
        self._pool.shutdown(wait=True, cancel_futures=True)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)

    def workers(self) -> list[multiprocessing.Process]:
        """The pool's live worker processes (see the class docstring)."""
        return [p for p in multiprocessing.active_children() if p.pid not in self._before]


def _flexfusion_environment() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k.startswith("FLEXFUSION_")}


def _set_environment(env: dict[str, str]) -> None:
    for key in [k for k in os.environ if k.startswith("FLEXFUSION_")]:
        del os.environ[key]
    os.environ.update(env)


def _init_worker(env: dict[str, str]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _set_environment(env)


# ---------------------------------------------------------------------------------------------
# the study folder: finished jobs kept on disk, resumable
# ---------------------------------------------------------------------------------------------
class StudyInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM during a study (``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StudyFolder:
    """A study's ``--out`` folder, which keeps every finished job.

    Entering it (before any job runs) creates the folder, takes its lock (one study at a time)
    and writes ``status.json`` (which also proves the folder writable). While it is active,
    :func:`map_jobs` stores each job's result as it completes in ``jobs/<key>.pickle`` (written
    atomically; the key is a hash of the job's function and arguments) and takes the results
    already there instead of computing them again: that is ``--resume``. On leaving,
    ``status.json`` says ``ok``, ``failed`` or ``interrupted`` (with the cause).

    A resumed study reuses a stored result whenever the job is the same call; it does not know
    whether the FMUs or the code changed meanwhile (start a new folder then). A job file is a
    pickle signed with this user's key (:func:`job_key`): ``MAGIC``, the HMAC-SHA256 of the
    pickle, the pickle. The signature is checked before anything is unpickled, so a job file
    that this user's studies did not write (another user's folder, a crafted or damaged file, an
    older unsigned one) is never loaded: its job runs again, with a warning.
    """

    STATUS = "status.json"
    JOBS = "jobs"
    MAGIC = b"FlexFusionJob1\0"

    def __init__(self, path: str | Path, *, resume: bool = False, command: str = "") -> None:
        self.path = Path(path)
        self.resume = resume
        self.command = command
        self.computed = 0          # jobs computed (and stored) in this session
        self.reused = 0            # jobs taken from the folder
        self._lock: Any = None
        self._token: Any = None

    # -- life cycle ------------------------------------------------------------------------
    def __enter__(self) -> StudyFolder:
        status = self.path / self.STATUS
        try:
            if self.path.exists() and not self.path.is_dir():
                raise StudyError(f"--out {self.path}: not a folder")
            if self.resume and not status.is_file():
                raise StudyError(f"--resume: {self.path} is not a study folder (no {self.STATUS})")
            if not self.resume and self.path.is_dir() and self.stored():
                raise StudyError(f"--out {self.path} holds {self.stored()} finished runs of a study "
                                 f"(status '{self._previous_status()}'): add --resume to continue it "
                                 "with them, or choose another --out")
            (self.path / self.JOBS).mkdir(parents=True, exist_ok=True)
            self._lock = FolderLock(self.path)
            self._lock.acquire()
        except FolderLockedError as exc:
            raise StudyError(f"--out {exc}: another study writes there") from None
        except OSError as exc:
            raise StudyError(f"--out {self.path}: {exc.strerror or exc}") from None
        try:
            self._write_status("running")
        except OSError as exc:
            self._lock.release()
            raise StudyError(f"--out {self.path}: cannot write: {exc.strerror or exc}") from None
        self._token = _ACTIVE_FOLDER.set(self)
        return self

    def __exit__(self, kind: type | None, exc: BaseException | None, tb: Any) -> None:
        _ACTIVE_FOLDER.reset(self._token)
        if kind is None:
            status, cause = "ok", None
        elif issubclass(kind, KeyboardInterrupt):
            status, cause = "interrupted", str(exc) or "SIGINT"
        else:
            status, cause = "failed", f"{kind.__name__}: {exc}"
        try:
            self._write_status(status, cause)
        except OSError:
            pass                   # the disk is what failed: the stored jobs are what counts
        finally:
            self._lock.release()

    def _previous_status(self) -> str:
        try:
            return str(json.loads((self.path / self.STATUS).read_text())["status"])
        except (OSError, ValueError, KeyError, TypeError):
            return "unreadable"

    def _write_status(self, status: str, cause: str | None = None) -> None:
        atomic_write_json(self.path / self.STATUS, {
            "status": status, "cause": cause, "command": self.command,
            "jobs_stored": self.stored(), "jobs_computed_now": self.computed,
            "jobs_reused_now": self.reused, "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")})

    # -- jobs ------------------------------------------------------------------------------
    @staticmethod
    def key(fn: Callable[..., Any], job: Any) -> str:
        """The name a job's result is stored under: a hash of the pickled call."""
        return hashlib.sha256(pickle.dumps((fn, job), protocol=5)).hexdigest()[:32]

    def _file(self, key: str) -> Path:
        return self.path / self.JOBS / f"{key}.pickle"

    def load(self, key: str) -> tuple[bool, Any]:
        """``(True, result)`` for the stored job ``key``, ``(False, None)`` otherwise: not
        there, not signed with this user's key (never unpickled, then), or unreadable."""
        try:
            data = self._file(key).read_bytes()
        except FileNotFoundError:
            return False, None
        except OSError as exc:
            warnings.warn(f"{self._file(key)}: cannot read it ({exc.strerror or exc}); the job runs again")
            return False, None
        n = len(self.MAGIC)
        secret = job_key()
        if secret is None or data[:n] != self.MAGIC or not hmac.compare_digest(
                data[n:n + 32], hmac.new(secret, data[n + 32:], "sha256").digest()):
            why = ("no private key folder" if secret is None else "an unsigned file (an older format)"
                   if data[:n] != self.MAGIC else "its signature is not this user's key's")
            warnings.warn(f"{self._file(key)}: not loaded: {why}; a job file this user's studies did "
                          "not write is never unpickled; the job runs again")
            return False, None
        try:
            value = pickle.loads(data[n + 32:])  # noqa: S301 - signed with this user's key (checked above)
        except Exception as exc:  # noqa: BLE001 - a result whose class is gone: the job runs again
            warnings.warn(f"{self._file(key)}: cannot read it ({type(exc).__name__}: {exc}); the job runs again")
            return False, None
        self.reused += 1
        return True, value

    def store(self, key: str, value: Any) -> None:
        """Store the result ``value`` of the job ``key``, signed (the class docstring); without
        a private key folder it is not stored (the study goes on, a resume computes it again)."""
        secret = job_key()
        if secret is None:
            return
        data = pickle.dumps(value, protocol=5)
        atomic_write_bytes(self._file(key), self.MAGIC + hmac.new(secret, data, "sha256").digest() + data)
        self.computed += 1

    def stored(self) -> int:
        return sum(1 for _ in (self.path / self.JOBS).glob("*.pickle"))


_ACTIVE_FOLDER: ContextVar[StudyFolder | None] = ContextVar("study_folder", default=None)
KEY_FILE = "study-jobs.key"


def job_key() -> bytes | None:
    """This user's key that signs the study job files (32 random bytes): made once, in
    ``<cache root>/keys/`` (else a folder in the temporary directory), a folder of mode 0700
    checked private with the file (:func:`fmus.common.disk_cache.private_folder`); None, with
    a warning, where neither can be used."""
    import secrets
    import tempfile

    from fmus.common import disk_cache
    root = disk_cache.cache_root()
    shared = Path(tempfile.gettempdir()) / f"flexfusion-{os.getuid()}"
    why = []
    for folder, top in ((root / "keys", root), (shared / "keys", shared)):
        path = folder / KEY_FILE
        try:
            disk_cache.private_folder(folder, top)
            if not path.exists():
                tmp = folder / f".{KEY_FILE}.{os.getpid()}"
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
                with os.fdopen(fd, "wb") as f:
                    f.write(secrets.token_bytes(32))
                try:
                    os.link(tmp, path)            # the first one made wins
                except FileExistsError:
                    pass
                finally:
                    os.unlink(tmp)
            disk_cache.check_private(path, folder=False)
            key = path.read_bytes()
            if len(key) == 32:
                return key
            why.append(f"{path}: not a key")
        except OSError as exc:
            why.append(str(exc))
    warnings.warn("no private folder for the key that signs study job files (" + "; ".join(why)
                  + "): finished jobs are not kept")
    return None


@contextmanager
def study_folder(path: str | Path, *, resume: bool = False, command: str = "") -> Iterator[StudyFolder]:
    """:class:`StudyFolder` for a study run from the command line: SIGTERM also ends it as a
    :class:`StudyInterrupted` (as SIGINT does), so either leaves status ``interrupted``."""
    def interrupt(signum: int, frame: Any) -> None:
        raise StudyInterrupted(signum)

    previous = {s: signal.signal(s, interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with StudyFolder(path, resume=resume, command=command) as folder:
            yield folder
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


# ---------------------------------------------------------------------------------------------
# running the jobs
# ---------------------------------------------------------------------------------------------
def submit(executor: Executor | None, fn: Callable[..., Any], *args: Any) -> Future:
    """``executor.submit(fn, *args)``; without an executor ``fn(*args)`` run here, as a finished
    Future (its ``result()`` raises what ``fn`` raised, as from a worker)."""
    if executor is not None:
        return executor.submit(fn, *args)
    f: Future = Future()
    try:
        f.set_result(fn(*args))
    except Exception as exc:  # noqa: BLE001 - raised again by result()
        f.set_exception(exc)
    return f


class WorkerLost(RuntimeError):
    """The worker process running a job died (killed by a signal, out of memory, os._exit)."""


def map_jobs(fn: Callable[..., Any], jobs: Sequence[Any], executor: Executor, *, desc: str = "",
             progress: bool = True, star: bool = False) -> list[Any]:
    """Run ``fn(job)`` (``fn(*job)`` with ``star``) for every job on ``executor``.

    Returns the results in job order. All jobs run to their end even when some fail; then
    :class:`StudyError` names the failed jobs and their errors, with the other results on
    ``exc.results``. Within an active :class:`StudyFolder`, each result is stored as it
    completes, and results stored earlier are taken instead of running their jobs again.

    When a worker of a :class:`ProcessPool` dies, the pool is restarted and the jobs it was
    running are retried once, each alone (so that a job that kills its worker again takes no
    other job with it); the pool holds only as many jobs as it has workers, so the jobs that
    were lost are known. (A Dask cluster reschedules the jobs of a lost worker itself.)
    """
    folder = _ACTIVE_FOLDER.get()
    n = len(jobs)
    keys = [StudyFolder.key(fn, job) for job in jobs] if folder else []
    results: list[Any] = [None] * n
    errors: dict[int, BaseException] = {}
    todo: deque[int] = deque()
    for i in range(n):
        found, results[i] = folder.load(keys[i]) if folder else (False, None)
        if not found:
            todo.append(i)
    restartable = isinstance(executor, ProcessPool)
    window = executor.max_workers if restartable else max(n, 1)
    retry: deque[int] = deque()           # jobs whose worker died once
    lost: set[int] = set()
    running: dict[Future, int] = {}
    broken = False
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n, initial=n - len(todo), desc=desc or getattr(fn, "__name__", "jobs"),
                   unit="run", file=sys.stderr, leave=False)
    try:
        while todo or retry or running:
            if broken and not running:
                executor.restart()
                broken = False
            if not broken:
                if retry and not running:
                    queue, count = retry, 1
                else:
                    queue, count = todo, 0 if retry else window - len(running)
                for _ in range(min(count, len(queue))):
                    i = queue.popleft()
                    try:
                        running[executor.submit(fn, *jobs[i]) if star else executor.submit(fn, jobs[i])] = i
                    except BrokenProcessPool:     # a worker died since the last wait
                        if not restartable:
                            raise
                        queue.appendleft(i)
                        broken = True
                        break
            if not running:
                continue
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                i = running.pop(fut)
                try:
                    results[i] = fut.result()
                except BrokenProcessPool as exc:
                    if not restartable:
                        errors[i] = exc
                    elif i in lost:
                        errors[i] = WorkerLost("its worker process died twice (killed by a signal, "
                                               "out of memory, or the job ended the process)")
                    else:
                        lost.add(i)
                        retry.append(i)
                    broken = restartable
                    continue
                except Exception as exc:  # noqa: BLE001 - collected and reported below
                    errors[i] = exc
                else:
                    if folder:
                        folder.store(keys[i], results[i])
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if errors:
        raise _failed(jobs, errors, results, folder)
    return results


def _failed(jobs: Sequence[Any], errors: dict[int, BaseException], results: list[Any],
            folder: StudyFolder | None) -> StudyError:
    """The :class:`StudyError` of :func:`map_jobs` whose jobs ``errors`` failed: the first
    three named with their errors, the others' ``results`` kept."""
    failed = sorted(errors)
    first = "; ".join(f"job {i} ({_describe(jobs[i])}): {type(errors[i]).__name__}: {errors[i]}"
                      for i in failed[:3])
    more = f" (and {len(failed) - 3} more)" if len(failed) > 3 else ""
    kept = f"; the {len(jobs) - len(failed)} finished are kept in {folder.path}" if folder else ""
    return StudyError(f"{len(failed)} of {len(jobs)} jobs failed: {first}{more}{kept}", results)


def _describe(job: Any, limit: int = 120) -> str:
    text = repr(job)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers K``, ``--scheduler ADDRESS``, ``--no-progress`` and ``--resume`` for a
    study's sub-command."""
    parser.add_argument("--workers", type=int, metavar="K",
                        help="local worker processes (default: the number of cores)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on a Dask distributed cluster (tcp://host:port), or 'local' "
                             "to start a Dask LocalCluster here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--resume", action="store_true",
                        help="continue the study in --out: reuse its finished runs, compute the rest")


def add_engine_arguments(parser: argparse.ArgumentParser, checked: str, checks: int, batched: str,
                         fmu: str, default: str = "batched") -> None:
    """``--engine batched|fmu`` (``default``) and ``--check-<checked> N`` (default ``checks``)
    for a study on the batched engine; ``batched`` and ``fmu`` say what each engine does with
    this study, ``checked`` names its units (``runs``, ``seeds``, ``cases``, ``candidates``)."""
    described = {"batched": batched, "fmu": fmu}
    described[default] += " (default)"
    parser.add_argument("--engine", choices=ENGINES, default=default,
                        help="; ".join(f"{e}: {described[e]}" for e in sorted(described, key=lambda e: e != default)))
    parser.add_argument(f"--check-{checked}", type=int, default=checks, metavar="N",
                        help=f"{checked} checked through the FMUs with the batched engine (default {checks}; "
                             f"0: none; they must agree to {CHECK_RTOL:g} relative)")


__all__ = ["StudyError", "RunArrays", "simulate", "open_executor", "ProcessPool", "map_jobs",
           "StudyFolder", "study_folder", "unrecorded", "require_recorded", "StudyInterrupted", "WorkerLost", "add_executor_arguments", "add_engine_arguments",
           "dataclass_from_scalars", "check_against_fmus", "compare_checks", "simulate_recorded", "CHECK_RTOL", "ENGINES",
           "check_engine", "check_picks", "submit"]


def dataclass_from_scalars(cls: type, scalars: dict[str, Any]) -> Any:
    """An instance of a parameter dataclass from a component's scalar FMU parameters
    (``name`` or ``name[i]``); names that are not fields are ignored, the rest keep defaults."""
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in scalars:
            kw[f.name] = scalars[f.name]
            continue
        items = {int(k[len(f.name) + 1:-1]): v for k, v in scalars.items()
                 if k.startswith(f.name + "[") and k.endswith("]")}
        if items:
            default = list(f.default) if isinstance(f.default, tuple) else []
            n = max(len(default), max(items))
            vals = (default + [0.0] * n)[:n]
            for i, v in items.items():
                vals[i - 1] = v
            kw[f.name] = tuple(vals)
    return cls(**kw)


# ---------------------------------------------------------------------------------------------
# the batched engine's check
# ---------------------------------------------------------------------------------------------
#: The relative difference allowed between a run on the batched engine
#: (:mod:`orchestration.batched`) and the same run through the FMUs.
CHECK_RTOL = 1e-12
#: A study's engines (``--engine``): the batched engine with a few runs checked through the
#: FMUs, or one co-simulation of the FMUs per run.
ENGINES = ("batched", "fmu")


def check_engine(engine: str, checks: int, option: str) -> None:
    """:class:`StudyError` for an unknown ``--engine`` or a negative number of runs to check
    (``option``, e.g. ``--check-runs``)."""
    if engine not in ENGINES:
        raise StudyError(f"--engine must be one of {', '.join(ENGINES)}, not {engine!r}")
    if checks < 0:
        raise StudyError(f"{option} must not be negative, not {checks}")


def check_picks(n: int, k: int) -> list[int]:
    """``k`` of ``n`` runs (their indices), spread evenly over them, first and last included:
    the runs a study checks through the FMUs."""
    import numpy as np
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, min(k, n))}) if n else []


def check_against_fmus(batched: dict[str, Any] | None, fmu: dict[str, Any] | None, what: str,
                       rtol: float = CHECK_RTOL) -> float:
    """The largest relative difference ``max|a - b| / max|b|`` between the quantities of a run
    on the batched engine and of the same run through the FMUs (``{name: array or number}``,
    the same names; None: the run failed): the check every study on the batched engine makes.

    Raises
    ------
    StudyError
        Naming ``what`` (the run: its seed, case or candidate), the quantity, the difference and
        the values where it is largest, if one exceeds ``rtol``, has another shape, or the run
        fails on one path only.
    """
    import numpy as np

    def stop(why: str) -> StudyError:
        return StudyError(f"batched engine against the FMUs, {what}: {why}; rerun with --engine fmu")

    if batched is None or fmu is None:
        if (batched is None) != (fmu is None):
            raise stop(f"the run fails on the {'batched engine' if batched is None else 'FMUs'} only")
        return 0.0
    if set(batched) != set(fmu):
        raise stop(f"other quantities ({', '.join(sorted(set(batched) ^ set(fmu)))})")
    worst = 0.0
    for name in fmu:
        a, b = np.asarray(batched[name], float), np.asarray(fmu[name], float)
        if a.shape != b.shape:
            raise stop(f"{name} has shape {a.shape}, not {b.shape}")
        d = float(np.max(np.abs(a - b), initial=0.0) / max(float(np.max(np.abs(b), initial=0.0)), 1e-300))
        if not d <= rtol:
            i = np.unravel_index(int(np.argmax(np.nan_to_num(np.abs(a - b), nan=np.inf))), a.shape)
            raise stop(f"{name} differs by {d:.3g} relative (batched {a[i]:.17g}, FMUs {b[i]:.17g}; "
                       f"allowed {rtol:g})")
        worst = max(worst, d)
    return worst


def compare_checks(checks: dict[str, Future], batched: dict[str, dict[str, Any]],
                   quantities: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
                   rtol: float = CHECK_RTOL) -> float:
    """Wait for each FMU check run ``checks[what]`` (a Future of a run's result) and compare it
    with the same run on the batched engine, ``batched[what]``, by :func:`check_against_fmus`:
    the ``quantities`` of each (default: every series but ``wall_time``); the largest relative
    difference.

    Raises
    ------
    StudyError
        A check run failed, or differs (naming ``what``).
    """
    def series(run: dict[str, Any]) -> dict[str, Any]:
        return quantities(run) if quantities else {k: v for k, v in run.items() if k != "wall_time"}

    worst = 0.0
    for what, fut in checks.items():
        try:
            fmu = fut.result()
        except Exception as exc:  # noqa: BLE001 - reported with its run
            raise StudyError(f"the FMU check run of {what} failed: {type(exc).__name__}: {exc}") from None
        worst = max(worst, check_against_fmus(series(batched[what]), series(fmu), what, rtol))
    return worst
