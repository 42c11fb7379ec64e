"""Studies: many independent scenario runs on a ``concurrent.futures`` executor.

A study (Monte Carlo over seeds, robustness cases, tuning) is a list of jobs, each a picklable
call such as ``simulate(scenario, overrides)``. :func:`open_executor` gives the executor they run
on: local processes by default, or a Dask ``distributed`` cluster when a scheduler address is
given (``"local"`` starts a ``LocalCluster`` on this machine). :func:`map_jobs` runs the jobs with
a progress bar and returns their results in job order, so a study's numbers do not depend on the
executor or the number of workers.

Worker processes are forked from a clean server process (``forkserver``), not from this one
(which may hold threads and loaded FMUs), and live as long as the executor; each run frees its
FMU instances and unloads their libraries. (Replacing workers with ``max_tasks_per_child``
deadlocks Python 3.11's ``ProcessPoolExecutor`` when jobs are queued, python/cpython#115634.)
"""
from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


class StudyError(RuntimeError):
    """A study that could not be done as asked; ``results`` holds what the jobs that succeeded
    returned (``None`` for the failed ones)."""

    def __init__(self, message: str, results: list[Any] | None = None) -> None:
        super().__init__(message)
        self.results = results


# ---------------------------------------------------------------------------------------------
# one job: a scenario run kept in memory
# ---------------------------------------------------------------------------------------------
class RunArrays:
    """A run's recorded signals in memory: ``r.time`` (n,), ``r["plant.p_tool"]`` -> (n, 2),
    ``r["plant.p_tool[1]"]`` or a scalar variable -> (n,); ``r.metrics`` the scenario's metrics."""

    def __init__(self, time: np.ndarray, columns: list[str], data: np.ndarray,
                 metrics: dict[str, float], wall_time: float, warnings: list[str]) -> None:
        self.time = time
        self.columns = columns
        self.data = data
        self.metrics = metrics
        self.wall_time = wall_time
        self.warnings = warnings

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        if name in self.columns:
            return self.data[:, self.columns.index(name)]
        prefix = name + "["
        idx = [i for i, c in enumerate(self.columns) if c.startswith(prefix)]
        if not idx:
            raise KeyError(f"{name!r} was not recorded (recorded: {', '.join(self.variables())})")
        idx.sort(key=lambda i: int(self.columns[i][len(prefix):-1]))
        return self.data[:, idx]

    def __contains__(self, name: str) -> bool:
        try:
            self[name]
        except KeyError:
            return False
        return True

    def variables(self) -> list[str]:
        """Recorded whole variables (``comp.var``), in column order."""
        return list(dict.fromkeys(c.split("[", 1)[0] for c in self.columns))


def simulate(scenario: str | Path | dict[str, Any], overrides: Sequence[str] = (),
             variables: Sequence[str] | None = None) -> RunArrays:
    """Run a scenario in memory (no files) and return its recorded signals and metrics.

    Parameters
    ----------
    scenario
        A scenario file or a parsed TOML document.
    overrides
        ``comp.param=value`` and ``scenario.seed=N`` strings (see :mod:`orchestration.scenario`).
    variables
        Keep only these recorded variables (``comp.var``); default all.

    Raises
    ------
    ScenarioError, RunError
        As :func:`orchestration.master.run`.
    """
    from . import metrics as _metrics
    from .master import CouplingWarning
    from .master import simulate as _simulate
    from .scenario import ScenarioError, load_scenario

    sc = load_scenario(scenario, tuple(overrides))
    columns = sc.record_columns()
    rows: list[np.ndarray] = []
    times: list[float] = []

    def sink(t: float, values: np.ndarray) -> None:
        times.append(t)
        rows.append(np.array(values, dtype=float))

    t0 = time.perf_counter()
    with warnings.catch_warnings():      # returned on RunArrays.warnings, not printed per run
        warnings.simplefilter("ignore", CouplingWarning)
        notes = _simulate(sc, sink)
    wall = time.perf_counter() - t0
    data = np.array(rows).reshape(len(rows), len(columns))
    run = RunArrays(np.array(times), columns, data, {}, wall, notes)
    for spec in sc.metrics:
        try:
            run.metrics.update(_metrics.compute(spec, run.time, run[spec.estimate], run[spec.truth],
                                                run[spec.truth_time] if spec.truth_time else None))
        except (ValueError, KeyError) as exc:
            raise ScenarioError(f"{sc.name}: metric '{spec.name}': {exc}") from None
    if variables is not None:
        keep = [i for i, c in enumerate(columns) if c.split("[", 1)[0] in set(variables)]
        missing = set(variables) - {columns[i].split("[", 1)[0] for i in keep}
        if missing:
            raise ScenarioError(f"{sc.name}: not recorded: {', '.join(sorted(missing))}")
        run.columns = [columns[i] for i in keep]
        run.data = data[:, keep]
    return run


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
        ``None``: a local process pool. An address (``tcp://host:8786``): the executor of a
        Dask ``distributed`` client connected to that scheduler. ``"local"``: a Dask
        ``LocalCluster`` started here (one thread per worker process).
    connect_timeout
        Seconds to wait for a remote scheduler.
    """
    if workers is not None and workers < 1:
        raise StudyError(f"--workers must be at least 1, not {workers}")
    if scheduler is None:
        ctx = multiprocessing.get_context("forkserver")
        # the fork server may be older than this process's settings: pass them on
        with ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1, mp_context=ctx,
                                 initializer=_set_environment,
                                 initargs=(_flexfusion_environment(),)) as ex:
            yield ex
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
            try:
                client = Client(scheduler, timeout=connect_timeout)
            except OSError as exc:
                raise StudyError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def _flexfusion_environment() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k.startswith("FLEXFUSION_")}


def _set_environment(env: dict[str, str]) -> None:
    for key in [k for k in os.environ if k.startswith("FLEXFUSION_")]:
        del os.environ[key]
    os.environ.update(env)


def map_jobs(fn: Callable[..., Any], jobs: Sequence[Any], executor: Executor, *, desc: str = "",
             progress: bool = True, star: bool = False) -> list[Any]:
    """Run ``fn(job)`` (``fn(*job)`` with ``star``) for every job on ``executor``.

    Returns the results in job order. All jobs run to their end even when some fail; then
    :class:`StudyError` names the failed jobs and their errors, with the other results on
    ``exc.results``.
    """
    futures: dict[Future, int] = {}
    for i, job in enumerate(jobs):
        futures[executor.submit(fn, *job) if star else executor.submit(fn, job)] = i
    results: list[Any] = [None] * len(futures)
    errors: list[tuple[int, BaseException]] = []
    bar = None
    if progress:
        import sys

        from tqdm import tqdm
        bar = tqdm(total=len(futures), desc=desc or getattr(fn, "__name__", "jobs"), unit="run",
                   file=sys.stderr, leave=False)
    try:
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                results[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - collected and reported below
                errors.append((i, exc))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if errors:
        errors.sort(key=lambda e: e[0])
        first = "; ".join(f"job {i} ({_describe(jobs[i])}): {type(e).__name__}: {e}"
                          for i, e in errors[:3])
        more = f" (and {len(errors) - 3} more)" if len(errors) > 3 else ""
        raise StudyError(f"{len(errors)} of {len(results)} jobs failed: {first}{more}", results)
    return results


def _describe(job: Any, limit: int = 120) -> str:
    text = repr(job)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers K``, ``--scheduler ADDRESS`` and ``--no-progress`` for a study's sub-command."""
    parser.add_argument("--workers", type=int, metavar="K",
                        help="local worker processes (default: the number of cores)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on a Dask distributed cluster (tcp://host:port), or 'local' "
                             "to start a Dask LocalCluster here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


__all__ = ["StudyError", "RunArrays", "simulate", "open_executor", "map_jobs",
           "add_executor_arguments", "dataclass_from_scalars"]


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
