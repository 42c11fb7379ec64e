"""Results of a run: a streaming CSV writer, ``metrics.json``, ``run.json`` and :class:`Result`.

Files in a run's folder:

``results.csv``
    Header ``"time","comp.var[1]",...`` (every name quoted, one column per scalar), then one row
    per recorded time; values written with ``repr`` (shortest round-trip form), so a rerun with
    the same scenario and seed is byte-identical. ``fmpy.util.read_csv`` reads it: its field
    names are exactly the scalar names ``comp.var[i]`` (dots and brackets kept). Rows are
    flushed as the run goes, so a failing run keeps what it produced.
``metrics.json``
    ``{metric name: {"value", "kind", "estimate", "truth", "against"}}`` (a band-pass metric
    gives ``name_max`` and ``name_mean``); ``against`` is ``"truth"`` when ``truth`` is plant
    truth, ``"reference"`` when it is a reference system's measurement (the Tracker).
``run.json``
    The resolved scenario, the overrides, package versions, wall time, status
    (``"ok"``/``"error"``) and the error message.
"""
from __future__ import annotations

import json
import math
import platform
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

CSV_NAME = "results.csv"
METRICS_NAME = "metrics.json"
RUN_NAME = "run.json"


class CsvWriter:
    """Write rows to ``results.csv`` as they come; flush every ``flush_every`` rows."""

    def __init__(self, path: Path, columns: list[str], flush_every: int = 200) -> None:
        for c in columns:
            if "," in c or '"' in c:
                raise ValueError(f"column name {c!r} must not contain ',' or '\"'")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f: TextIO | None = open(self.path, "w", newline="\n")
        self._f.write(",".join(f'"{c}"' for c in ["time", *columns]) + "\n")
        self._f.flush()
        self.flush_every = flush_every
        self.rows = 0

    def __call__(self, t: float, values: np.ndarray) -> None:
        assert self._f is not None
        self._f.write(repr(float(t)) + "," + ",".join(map(repr, values.tolist())) + "\n"
                      if len(values) else repr(float(t)) + "\n")
        self.rows += 1
        if self.rows % self.flush_every == 0:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def __enter__(self) -> "CsvWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_results_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Column names (without ``time``) and the data (n, 1 + columns) of a ``results.csv``."""
    path = Path(path)
    with open(path) as f:
        header = f.readline().rstrip("\n")
    names = [h.strip('"') for h in header.split(",")]
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        data = np.zeros((0, len(names)))
    return names[1:], data


def _json_safe(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(path: Path, data: Any) -> None:
    Path(path).write_text(json.dumps(_json_safe(data), indent=2, sort_keys=False) + "\n")


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
    """
    out_dir: Path
    time: np.ndarray
    columns: list[str]
    data: np.ndarray                      # (n, len(columns))
    metrics: dict[str, float] = field(default_factory=dict)
    against: dict[str, str] = field(default_factory=dict)    # metric name -> truth | reference | ...
    status: str = "ok"
    error: str | None = None
    warnings: list[str] = field(default_factory=list)

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
        """Read a run's folder (``results.csv``, ``metrics.json``, ``run.json``)."""
        out_dir = Path(out_dir)
        csv = out_dir / CSV_NAME
        if not csv.is_file():
            raise FileNotFoundError(f"{out_dir}: no {CSV_NAME} (not a run folder)")
        columns, data = read_results_csv(csv)
        metrics, against = {}, {}
        if (out_dir / METRICS_NAME).is_file():
            for name, e in json.loads((out_dir / METRICS_NAME).read_text()).items():
                if isinstance(e, dict):
                    metrics[name], against[name] = e["value"], e["against"]
                else:                       # a run written before metrics said what they compare
                    metrics[name] = e
        status, error, warns = "ok", None, []
        if (out_dir / RUN_NAME).is_file():
            info = json.loads((out_dir / RUN_NAME).read_text())
            status, error, warns = info.get("status", "ok"), info.get("error"), info.get("warnings", [])
        return cls(out_dir, data[:, 0].copy(), columns, data[:, 1:], metrics, against, status, error, warns)


__all__ = ["CsvWriter", "Result", "read_results_csv", "write_json", "versions",
           "CSV_NAME", "METRICS_NAME", "RUN_NAME"]
