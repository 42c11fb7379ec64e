"""Results of a run: a crash-safe CSV writer, ``metrics.json``, ``run.json``, the folder lock
and :class:`Result`.

Files in a run's folder:

``results.csv``
    Header ``"time","comp.var[1]",...`` (every name quoted, one column per scalar), then one row
    per recorded time; values written with ``repr`` (shortest round-trip form), so a rerun with
    the same scenario and seed is byte-identical. ``fmpy.util.read_csv`` reads it: its field
    names are exactly the scalar names ``comp.var[i]`` (dots and brackets kept). Rows are
    written in blocks of whole lines as the run goes (one ``write`` per block), and a write that
    fails (disk full) is cut back to the last whole row, so a run that fails, is interrupted or
    is killed keeps every row it wrote and the file stays readable.
``metrics.json``
    ``{metric name: {"value", "unit", "kind", "estimate", "truth", "against"}}`` (a band-pass
    metric gives ``name_max`` and ``name_mean``); ``against`` is ``"truth"`` when ``truth`` is
    plant truth, ``"reference"`` when it is a reference system's measurement (the Tracker).
``run.json``
    The resolved scenario, the overrides, package versions (from the run's end on), wall
    time, ``status``, ``error`` (the cause), ``rows`` (data rows in ``results.csv``),
    ``time_reached`` (s, the last row's time) and ``units``: ``{"time": "s", column: unit}``
    for every column of ``results.csv``, each as its FMU's modelDescription gives it (``""``
    when it gives none), there from the run's start on. The units sit beside the CSV, not in
    it: a second header row would be read as a data row by ``fmpy.util.read_csv``
    (``numpy.genfromtxt``) and by ``pandas.read_csv``, and would change ``results.csv``. Written atomically (a temporary file renamed over it): ``"running"`` when the
    run starts, then ``"ok"``, ``"failed"`` or ``"interrupted"`` (SIGINT, SIGTERM). A folder
    still saying ``"running"`` that no process owns was killed: :meth:`Result.load` reports it
    as ``"interrupted"``.
``.lock``
    The lock file of :func:`own_folder` (one run per folder at a time).
"""
from __future__ import annotations

import errno
import json
import math
import os
import platform
import sys
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .safe_io import LOCK_NAME, FolderLock, FolderLockedError, atomic_write_text, is_locked

CSV_NAME = "results.csv"
METRICS_NAME = "metrics.json"
RUN_NAME = "run.json"
#: what a run writes into its folder (``plot`` adds the PNGs): an earlier run's are replaced
#: only with ``force``
RESULT_FILES = (CSV_NAME, METRICS_NAME, RUN_NAME, "variables.png", "tool_path.png")


class OutputError(RuntimeError):
    """The output folder cannot be used or written (another run owns it, it holds an earlier
    run's results, an OS error such as a full disk); ``out_dir`` is the folder once the run has
    written to it."""

    out_dir: Path | None = None


class ResultWarning(UserWarning):
    """A run folder read by :meth:`Result.load` holds a run that did not end ``ok``."""


@contextmanager
def own_folder(out: Path, force: bool = False) -> Iterator[Path]:
    """Own the output folder ``out`` for one run: create it and hold an exclusive
    ``fcntl.flock`` on its ``.lock`` file (released by the OS when the process ends, however it
    ends).

    Raises
    ------
    OutputError
        Another process holds the lock; the folder holds an earlier run's results
        (:data:`RESULT_FILES`) and ``force`` is false (with ``force`` they are removed, other
        files are left alone); an OS error creating or opening it.
    """
    out = Path(out)
    lock = FolderLock(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        lock.acquire()
    except FolderLockedError:
        raise OutputError(f"another run is writing to {out} (it holds {out / LOCK_NAME}); "
                          "wait for it or choose another --out") from None
    except OSError as exc:
        raise OutputError(f"cannot use the output folder {out}: {exc.strerror or exc}") from None
    try:
        old = [name for name in RESULT_FILES if (out / name).exists()]
        if old and not force:
            raise OutputError(f"{out} holds the results of an earlier run ({', '.join(old)}); "
                              "give --force to replace them or choose another --out")
        try:
            for name in old:
                (out / name).unlink()
        except OSError as exc:
            raise OutputError(f"cannot remove the earlier results in {out}: {exc.strerror or exc}") from None
        yield out
    finally:
        lock.release()


class CsvWriter:
    """Write rows to ``results.csv`` in blocks of ``flush_every`` whole rows (and the rest at
    :meth:`close`), each block with one ``os.write``; a block that cannot be written whole
    (disk full) is cut back to the last whole row before the error propagates.

    ``rows`` and ``time_reached`` describe what is on disk.
    """

    def __init__(self, path: Path, columns: list[str], flush_every: int = 200) -> None:
        for c in columns:
            if "," in c or '"' in c:
                raise ValueError(f"column name {c!r} must not contain ',' or '\"'")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self.flush_every = flush_every
        self._pending: list[str] = []
        self._pending_t = 0.0
        self._size = 0
        self.rows = 0
        self.time_reached: float | None = None
        self._write((",".join(f'"{c}"' for c in ["time", *columns]) + "\n").encode())

    def __call__(self, t: float, values: np.ndarray) -> None:
        self._pending.append(repr(float(t)) + "," + ",".join(map(repr, values.tolist())) + "\n"
                             if len(values) else repr(float(t)) + "\n")
        self._pending_t = t
        if len(self._pending) >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        """Write the pending rows (whole, or none of them)."""
        if self._pending:
            self._write("".join(self._pending).encode())
            self.rows += len(self._pending)
            self.time_reached = float(self._pending_t)
            self._pending.clear()

    def _write(self, data: bytes) -> None:
        assert self._fd is not None
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._fd, view):]
        except OSError:
            self._pending.clear()            # lost with the block: not on disk
            os.ftruncate(self._fd, self._size)
            raise
        self._size += len(data)

    def close(self) -> None:
        """Flush the pending rows and close the file (closed even when the flush fails)."""
        if self._fd is not None:
            try:
                self.flush()
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> "CsvWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_results_csv(path: Path) -> tuple[list[str], np.ndarray, bool]:
    """Column names (without ``time``), the data (n, 1 + columns) of a ``results.csv`` up to
    its last whole row, and whether a torn last row (no line end, or fields missing) was left
    out."""
    with open(path, "rb") as f:
        lines = f.read().split(b"\n")
    names = [h.strip('"') for h in lines[0].decode().split(",")]
    rows = lines[1:]
    torn = bool(rows[-1]) if rows else False      # text after the last line end
    rows = [r for r in rows[:-1] if r] if rows else []
    if rows and rows[-1].count(b",") != len(names) - 1:
        torn, rows = True, rows[:-1]
    if not rows:
        return names[1:], np.zeros((0, len(names))), torn
    data = np.loadtxt([r.decode() for r in rows], delimiter=",", ndmin=2)
    return names[1:], data, torn


def json_safe(x: Any) -> Any:
    """``x`` as plain JSON data: the one sanitiser of the JSON files with numbers from a run.

    Dict keys become strings, tuples and numpy arrays lists, numpy scalars Python numbers, paths
    strings; a NaN becomes ``null`` and an infinity ``"inf"``/``"-inf"`` (strict JSON has
    neither, and an infinite bound or error is information worth keeping)."""
    if isinstance(x, np.ndarray):
        x = x.tolist()
    elif isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically: a temporary file in the same folder, synced, renamed over ``path``
    (a reader sees the old file or the new one, never a part).

    On a full disk the temporary file may find no free block while the old file holds some:
    then the old file is overwritten in place (truncating it frees its blocks first), so that a
    run's final status still reaches ``run.json``."""
    text = json.dumps(json_safe(data), indent=2, sort_keys=False) + "\n"
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        if exc.errno != errno.ENOSPC or not Path(path).exists():
            raise
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())


def versions() -> dict[str, str]:
    """Versions of Python and of the packages a run depends on."""
    from importlib import metadata
    out = {"python": platform.python_version(), "platform": sys.platform}
    for pkg in ("flexfusion", "fmpy", "pythonfmu", "numpy", "scipy"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


@dataclass
class Result:
    """A run's results: ``result["plant.p_tool"]`` is an (n, 2) array, ``result.time`` (n,).

    ``result["plant.p_tool[1]"]`` gives one column; a scalar variable gives an (n,) array.
    ``units`` the unit of ``time`` and of every column (``{"plant.p_tool[1]": "m", ...}``,
    ``""`` for none; empty for a folder written before run.json had them), ``metric_units``
    each metric's (``"1"``: dimensionless). :meth:`to_pandas` gives a ``pandas.DataFrame``.
    ``status`` is ``"ok"`` only for a run that ended ok with all its rows; otherwise
    ``error`` says why (and :meth:`load` warns). The one container of a run's results: as a
    run returns it (:func:`orchestration.master.run_loaded`: ``wall_time`` the seconds the
    stepping took; ``out_dir`` None for a run in memory) or read from a run folder
    (:meth:`load`; ``wall_time`` NaN, run.json has it).
    """
    out_dir: Path | None
    time: np.ndarray
    columns: list[str]
    data: np.ndarray                      # (n, len(columns))
    metrics: dict[str, float] = field(default_factory=dict)
    metric_units: dict[str, str] = field(default_factory=dict)   # metric name -> unit ("" if none)
    against: dict[str, str] = field(default_factory=dict)    # metric name -> truth | reference | ...
    status: str = "ok"
    error: str | None = None
    warnings: list[str] = field(default_factory=list)
    wall_time: float = float("nan")
    units: dict[str, str] = field(default_factory=dict)      # "time" and column -> unit ("" if none)

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        if name in self.columns:
            return self.data[:, self.columns.index(name)]
        idx = [i for i, c in enumerate(self.columns) if c.startswith(name + "[") and c.endswith("]")
               and c[len(name) + 1:-1].isdigit()]
        if not idx:
            raise KeyError(f"{name!r} was not recorded (recorded: {', '.join(self.variables())})")
        idx.sort(key=lambda i: int(self.columns[i][len(name) + 1:-1]))
        return self.data[:, idx]

    def set_metrics(self, described: dict[str, dict[str, Any]]) -> None:
        """Take the ``metrics.json`` entries ``{name: {"value", "unit", "against", ...}}``."""
        self.metrics = {name: e["value"] for name, e in described.items()}
        self.metric_units = {name: e.get("unit", "") for name, e in described.items()}
        self.against = {name: e["against"] for name, e in described.items()}

    def to_pandas(self) -> Any:
        """A ``pandas.DataFrame`` of the rows: the column ``time`` then one column per recorded
        scalar, as in ``results.csv``; ``frame.attrs["units"]`` is :attr:`units`.

        Raises
        ------
        ImportError
            pandas is not installed (it is no dependency of flexfusion).
        """
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("Result.to_pandas() needs pandas, which is not installed "
                              "(install it with pip: pip install pandas)") from None
        frame = pd.DataFrame(np.column_stack([self.time, self.data]) if len(self.columns) else
                             self.time[:, None], columns=["time", *self.columns])
        frame.attrs["units"] = dict(self.units)
        return frame

    def __contains__(self, name: str) -> bool:
        try:
            self[name]
            return True
        except KeyError:
            return False

    def variables(self) -> list[str]:
        """Recorded whole variables (``comp.var``), in column order."""
        out: list[str] = []
        for c in self.columns:
            base = c.split("[", 1)[0] if c.endswith("]") else c
            if base not in out:
                out.append(base)
        return out

    @classmethod
    def load(cls, out_dir: str | Path) -> "Result":
        """Read a run's folder (``results.csv`` up to its last whole row, ``metrics.json``,
        ``run.json``).

        A run that did not end ok (``run.json`` says ``failed`` or ``interrupted``, still says
        ``running`` with no process owning the folder, is missing, or ``results.csv`` lacks rows
        that ``run.json`` counts) gives a :class:`ResultWarning` naming the status, the cause
        and the time the rows reach; ``status`` and ``error`` say the same.
        """
        out_dir = Path(out_dir)
        csv = out_dir / CSV_NAME
        if not csv.is_file():
            raise FileNotFoundError(f"{out_dir}: no {CSV_NAME} (not a run folder)")
        columns, data, torn = read_results_csv(csv)
        metrics, against, units = {}, {}, {}
        if (out_dir / METRICS_NAME).is_file():
            for name, e in json.loads((out_dir / METRICS_NAME).read_text()).items():
                if isinstance(e, dict):
                    metrics[name], against[name], units[name] = e["value"], e["against"], e.get("unit", "")
                else:                       # a run written before metrics said what they compare
                    metrics[name] = e
        info: dict[str, Any] = {"status": "unknown", "error": f"no {RUN_NAME}"}
        if (out_dir / RUN_NAME).is_file():
            info = json.loads((out_dir / RUN_NAME).read_text())
        status, error = info.get("status", "unknown"), info.get("error")
        if status == "error":                      # the name before "failed"
            status = "failed"
        if status == "running" and not is_locked(out_dir):
            status, error = "interrupted", "the run ended without a final status (killed or crashed)"
        if status == "ok" and len(data) != info.get("rows", len(data)):
            status, error = "failed", (f"{CSV_NAME} holds {len(data)} of the {info['rows']} rows "
                                       "the run wrote (cut short after the run)")
        if status != "ok":
            reached = f"results up to t = {data[-1, 0]:.6g} s" if len(data) else "no result row"
            warnings.warn(f"{out_dir}: the run is {status} ({error}); {reached}"
                          + ("; a torn last row was left out" if torn else ""), ResultWarning,
                          stacklevel=2)
        return cls(out_dir, data[:, 0].copy(), columns, data[:, 1:], metrics, units, against, status,
                   error, info.get("warnings", []), units=info.get("units", {}))


__all__ = ["CsvWriter", "Result", "ResultWarning", "OutputError", "own_folder", "read_results_csv",
           "write_json", "json_safe", "versions", "CSV_NAME", "METRICS_NAME", "RUN_NAME", "LOCK_NAME", "RESULT_FILES"]
