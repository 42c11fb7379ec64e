"""A recorded log as signals: reading (CSV, HDF5), checking and sampling it (no FMI).

The :class:`~fmus.robot_plant.log_replay_fmu.LogReplay` FMU plays a log through this module.

Column map (parameter ``columns``): entries ``output = column`` or ``output = column [unit]``
separated by ``;`` or new lines. ``output`` is a scalar output (``acc_s[3]``) or a whole vector
(``q_m_meas = encoder.q_m_meas`` maps ``q_m_meas[i]`` to the column ``encoder.q_m_meas[i]``).
The optional ``[unit]`` is the column's unit; it is converted to the output's SI unit by
:data:`UNIT_FACTORS` (e.g. ``acc_s[1] = ax [g]``, ``q_m_meas[1] = enc1 [deg]``). A column whose
name ends in a unit (``acc x [g]``) is that column, in SI; ``acc x [g] [g]`` converts it.

Time: the column ``time_column`` holds the log's time in seconds; the log time of simulation
time ``t`` is ``t + time_offset``. It must increase strictly, and no interval between rows may
exceed ``max_gap``. Sampling is ``"hold"`` (the newest row at or before the time: a recorded
sensor's sample-and-hold, bit-exact at the recording rate) or ``"linear"`` (interpolation
between the two rows around the time).

Every problem raises :class:`~fmus.common.parameters.ParameterError` naming the file and the
column or row.
"""
from __future__ import annotations

import csv
import math
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from fmus.common.parameters import ParameterError, param
from fmus.common.sample_time import TIME_TOL

#: Column units that are converted (factor to the SI unit); a column in the output's own SI
#: unit needs no ``[unit]``. g is the standard gravity, 9.80665 m/s^2 by definition (the
#: CGPM 1901, 3rd meeting; ISO 80000-3).
UNIT_FACTORS: dict[str, tuple[str, float]] = {
    "deg": ("rad", math.pi / 180.0), "mrad": ("rad", 1e-3), "urad": ("rad", 1e-6),
    "deg/s": ("rad/s", math.pi / 180.0), "deg/s2": ("rad/s2", math.pi / 180.0),
    "mm": ("m", 1e-3), "mm/s": ("m/s", 1e-3), "mm/s2": ("m/s2", 1e-3),
    "g": ("m/s2", 9.80665), "ms": ("s", 1e-3), "us": ("s", 1e-6), "ns": ("s", 1e-9),
    "kN": ("N", 1e3), "kN.m": ("N.m", 1e3), "N.mm": ("N.m", 1e-3),
}

#: File suffixes of the formats read.
CSV_SUFFIXES = (".csv", ".txt")
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")


@dataclass(frozen=True)
class LogReplayParameters:
    """Parameters of the LogReplay FMU."""

    log_file: str = param("", "1", "the log: CSV (header row of column names) or HDF5 (one 1-D "
                          "dataset per column, named by its path in the file; needs h5py)")
    columns: str = param("", "1", "column map 'output = column [unit]; ...' (see "
                         "fmus.robot_plant.log_replay_model)")
    time_column: str = param("time", "1", "the column of the log time (s)")
    interpolation: str = param("hold", "1", "'hold': the newest row at or before the time (a "
                               "sensor's sample-and-hold); 'linear': interpolated",
                               choices=("hold", "linear"))
    time_offset: float = param(0.0, "s", "log time at simulation time 0 (log time = t + offset)")
    max_gap: float = param(0.05, "s", "largest interval allowed between rows", low=0.0,
                           low_inclusive=False, source="assumed: 50 samples of a 1 kHz robot "
                           "controller log, 5 of a 100 Hz one")


@dataclass(frozen=True)
class Mapping:
    """One output scalar fed by one column, times a unit factor."""

    output: str
    column: str
    factor: float


def parse_columns(text: str, outputs: dict[str, tuple[int | None, str]], available: Sequence[str],
                  where: str) -> list[Mapping]:
    """The column map ``text`` (module docstring) against the ``outputs`` ``{name: (size, SI
    unit)}`` (size None: a scalar) and the log's ``available`` column names, as one
    :class:`Mapping` per output scalar; ``where`` (e.g. "log 'x.csv'") begins every error
    message (:class:`ParameterError`)."""
    mappings: list[Mapping] = []
    seen: set[str] = set()
    for raw in text.replace("\n", ";").split(";"):
        entry = raw.strip()
        if not entry:
            continue
        out, eq, col = (s.strip() for s in entry.partition("="))
        if not eq or not out or not col:
            raise ParameterError(f"{where}: column map entry {entry!r} is not 'output = column [unit]'")
        unit = None
        if col.endswith("]") and " [" in col and col not in available:   # "name [unit]" is a
            col, unit = col[:-1].rsplit(" [", 1)                            # column name too
            col, unit = col.strip(), unit.strip()
        base, _, index = out.partition("[")
        if base not in outputs:
            raise ParameterError(f"{where}: column map: '{out}' is not an output of LogReplay "
                                 f"(outputs: {', '.join(outputs)})")
        size, si = outputs[base]
        factor = 1.0
        if unit is not None and unit != si:
            if unit not in UNIT_FACTORS or UNIT_FACTORS[unit][0] != si:
                known = [u for u, (s, _) in UNIT_FACTORS.items() if s == si]
                raise ParameterError(f"{where}: column map: unit '{unit}' of column '{col}' cannot be "
                                     f"converted to the unit {si} of '{out}' (known: "
                                     f"{', '.join([si] + known)})")
            factor = UNIT_FACTORS[unit][1]
        if index:
            pairs = [(out, col)]
            if size is None or not index.endswith("]") or not index[:-1].isdigit() \
                    or not 1 <= int(index[:-1]) <= size:
                raise ParameterError(f"{where}: column map: '{out}' is not an output of LogReplay "
                                     f"('{base}' has {size or 'no'} elements)")
        elif size is None:
            pairs = [(out, col)]
        elif col in available:      # one column for every element is a mistake, not a broadcast
            raise ParameterError(f"{where}: column map: '{out}' is a vector of {size} and '{col}' one "
                                 f"column: map the elements one by one ('{out}[1] = ...') or the "
                                 f"vector to columns '{col}[1]'...'{col}[{size}]' ('{out} = {col}')")
        else:
            pairs = [(f"{out}[{i + 1}]", f"{col}[{i + 1}]") for i in range(size)]
        for o, c in pairs:
            if c not in available:
                raise ParameterError(f"{where}: column '{c}' (for '{o}') is not in the log "
                                     f"(columns: {', '.join(available)})")
            if o in seen:
                raise ParameterError(f"{where}: column map: '{o}' is mapped twice")
            seen.add(o)
            mappings.append(Mapping(o, c, factor))
    return mappings


def column_names(path: Path) -> list[str]:
    """The column names of the log file ``path`` (CSV header, or the 1-D datasets of an HDF5
    file, by their paths in it)."""
    if path.suffix.lower() in HDF5_SUFFIXES:
        h5py = _h5py(path)
        names: list[str] = []
        with _hdf5(path) as f, _hdf5_errors(path):
            f.visititems(lambda name, obj: names.append(name)
                         if isinstance(obj, h5py.Dataset) and obj.ndim == 1 else None)
        return names
    with _csv_reader(path) as reader:
        return [c.strip() for c in next(reader, [])]


#: HDF5 dataset kinds read as numbers (numpy ``dtype.kind``): float, signed and unsigned integer.
HDF5_NUMBER_KINDS = "fiu"


def read_columns(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    """The columns ``names`` of the log file ``path`` as float arrays; an empty or non-numeric
    cell (CSV) or a dataset of another type than float or integer (HDF5: text, complex,
    compound, boolean) is an error naming its column (and row)."""
    if path.suffix.lower() in HDF5_SUFFIXES:
        out = {}
        with _hdf5(path) as f, _hdf5_errors(path):
            for n in names:
                dataset = f[n]
                if dataset.dtype.kind not in HDF5_NUMBER_KINDS:
                    raise ParameterError(f"log '{path}': dataset '{n}' holds {dataset.dtype} values, "
                                         "not numbers (float or integer)")
                out[n] = np.asarray(dataset[()], dtype=float)
        lengths = {len(v) for v in out.values()}
        if len(lengths) > 1:
            raise ParameterError(f"log '{path}': the datasets {', '.join(names)} differ in length "
                                 f"({', '.join(f'{n}: {len(v)}' for n, v in out.items())})")
    else:
        with _csv_reader(path) as reader:
            header = [c.strip() for c in next(reader, [])]
            idx = [header.index(n) for n in names]
            rows: list[list[float]] = []
            for row_no, row in enumerate(reader, start=1):
                if not row:
                    continue
                try:
                    rows.append([float(row[i]) for i in idx])
                except (ValueError, IndexError):
                    bad = next(n for n, i in zip(names, idx) if i >= len(row) or not _is_float(row[i]))
                    cell = row[header.index(bad)] if header.index(bad) < len(row) else ""
                    raise ParameterError(f"log '{path}': row {row_no} (line {row_no + 1}): column "
                                         f"'{bad}' is {cell.strip()!r}, not a number (a gap in the "
                                         "data)") from None
        data = np.array(rows, dtype=float).reshape(len(rows), len(names))
        out = {n: data[:, j] for j, n in enumerate(names)}
    for n, v in out.items():
        bad = np.flatnonzero(~np.isfinite(v))
        if len(bad):
            raise ParameterError(f"log '{path}': row {bad[0] + 1}: column '{n}' is {float(v[bad[0]])} "
                                 "(a gap in the data)")
    return out


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


@contextmanager
def _csv_reader(path: Path) -> Iterator[Any]:
    """A ``csv.reader`` of the log ``path`` (UTF-8 text); what is not (a binary file, a field
    past the csv module's limit, a NUL byte in a quoted field) is a :class:`ParameterError`."""
    try:
        fh = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise ParameterError(f"log '{path}': cannot read: {exc.strerror or exc}") from None
    with fh:
        reader = csv.reader(fh)
        try:
            yield reader
        except UnicodeDecodeError as exc:
            raise ParameterError(f"log '{path}': not a CSV file of UTF-8 text (near line "
                                 f"{reader.line_num + 1}: {exc.reason})") from None
        except csv.Error as exc:
            raise ParameterError(f"log '{path}': line {reader.line_num}: not CSV: {exc}") from None


def _hdf5(path: Path) -> Any:
    """The HDF5 file ``path``, open for reading; :class:`ParameterError` if it is not one."""
    h5py = _h5py(path)
    try:
        return h5py.File(path, "r")
    except (OSError, ValueError) as exc:
        raise ParameterError(f"log '{path}': not a readable HDF5 file ({' '.join(str(exc).split())})") from None


@contextmanager
def _hdf5_errors(path: Path) -> Iterator[None]:
    """h5py's errors of a damaged file (a broken link, an unreadable chunk) as :class:`ParameterError`."""
    try:
        yield
    except ParameterError:
        raise
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise ParameterError(f"log '{path}': cannot read the HDF5 file ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())})") from None


def _h5py(path: Path):
    try:
        import h5py
    except ImportError:
        raise ParameterError(f"log '{path}': reading HDF5 needs the package h5py, which this "
                             "Python does not have: pip install 'flexfusion[replay]' (or h5py)") from None
    return h5py


class RecordedLog:
    """A checked log: its times and the mapped outputs' values, sampled by :meth:`sample`.

    Built from ``p``, the :class:`LogReplayParameters` (file, column map, time column, offset,
    largest gap, interpolation), and ``outputs``, the outputs a column may feed ``{name: (size,
    SI unit)}`` (:func:`parse_columns`); every problem raises :class:`ParameterError`.

    ``stamp`` names the output that, when a column is mapped to it, holds each row's sample
    time in log time (a sensor's recorded ``t_meas``): :meth:`sample` then gives it as the time
    the values stand for. Immutable once built (read-only arrays), so a saved FMU state shares
    it instead of copying.
    """

    def __init__(self, p: LogReplayParameters, outputs: dict[str, tuple[int | None, str]],
                 stamp: str | None = None) -> None:
        if not p.log_file:
            raise ParameterError("parameter 'log_file' is empty: give the log to replay")
        path = Path(p.log_file)
        if not path.is_file():
            raise ParameterError(f"log '{path}': file not found (parameter 'log_file')")
        if path.suffix.lower() not in CSV_SUFFIXES + HDF5_SUFFIXES:
            raise ParameterError(f"log '{path}': unknown format '{path.suffix}' (CSV: "
                                 f"{', '.join(CSV_SUFFIXES)}; HDF5: {', '.join(HDF5_SUFFIXES)})")
        where = f"log '{path}'"
        available = column_names(path)
        if p.time_column not in available:
            raise ParameterError(f"{where}: the time column '{p.time_column}' is not in the log "
                                 f"(parameter 'time_column'; columns: {', '.join(available)})")
        self.mappings = parse_columns(p.columns, outputs, available, where)
        if not self.mappings:
            raise ParameterError(f"{where}: parameter 'columns' maps no column to an output")
        names = list(dict.fromkeys([p.time_column] + [m.column for m in self.mappings]))
        data = read_columns(path, names)
        times = data[p.time_column]
        if len(times) < 2:
            raise ParameterError(f"{where}: {len(times)} data row(s); a log needs at least 2")
        steps = np.diff(times)
        bad = np.flatnonzero(steps <= 0.0)
        if len(bad):
            i = bad[0]
            raise ParameterError(f"{where}: time is not increasing at row {i + 2}: "
                                 f"{p.time_column} = {float(times[i + 1])!r} after {float(times[i])!r} in row {i + 1}")
        gaps = np.flatnonzero(steps > p.max_gap * (1 + 1e-9))
        if len(gaps):
            i = gaps[0]
            raise ParameterError(f"{where}: a gap of {steps[i]:.6g} s between rows {i + 1} and {i + 2} "
                                 f"({p.time_column} {float(times[i])!r} -> {float(times[i + 1])!r}) exceeds the "
                                 f"parameter max_gap = {p.max_gap:.6g} s")
        self.path = path
        self.times = times
        self.values = np.column_stack([data[m.column] * m.factor if m.factor != 1.0 else data[m.column]
                                       for m in self.mappings])
        self.offset = float(p.time_offset)
        self.hold = p.interpolation == "hold"
        self._stamp = next((j for j, m in enumerate(self.mappings) if m.output == stamp), None)
        if self._stamp is not None and not self.hold:
            raise ParameterError(f"{where}: column map: '{stamp}' is mapped, but with interpolation "
                                 "= 'linear' the values stand for the current time: map no stamp")
        for a in (self.times, self.values):
            a.flags.writeable = False

    def __deepcopy__(self, memo: dict) -> "RecordedLog":
        return self

    def _row(self, t: float) -> tuple[int, float]:
        """The index of the newest row at or before simulation time ``t``, and its log time."""
        t_log = t + self.offset
        i = int(np.searchsorted(self.times, t_log + TIME_TOL, side="right")) - 1
        if i < 0 or t_log > self.times[-1] + TIME_TOL:
            raise ParameterError(
                f"log '{self.path}': simulation time {t:.6g} s is log time {t_log:.6g} s, outside "
                f"the log ({self.times[0]:.6g} ... {self.times[-1]:.6g} s; parameter 'time_offset' "
                f"= {self.offset:.6g} s)")
        return i, t_log

    def sample(self, t: float) -> tuple[np.ndarray, float]:
        """The mapped values at simulation time ``t`` and the simulation time they stand for:
        the held row's stamp or time (hold), or ``t`` (linear)."""
        i, t_log = self._row(t)
        if self.hold:
            taken = self.values[i, self._stamp] if self._stamp is not None else self.times[i]
            return self.values[i], float(taken - self.offset)
        if i == len(self.times) - 1:
            return self.values[i], t
        w = (t_log - self.times[i]) / (self.times[i + 1] - self.times[i])
        if w <= 0.0:
            return self.values[i], t
        return self.values[i] + w * (self.values[i + 1] - self.values[i]), t


__all__ = ["LogReplayParameters", "RecordedLog", "Mapping", "parse_columns", "read_columns",
           "column_names", "UNIT_FACTORS"]
