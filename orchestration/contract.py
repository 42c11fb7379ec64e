"""``flexfusion check-estimator``: does an FMU meet the estimator contract?

The contract (docs/estimator_contract.md; the table in :mod:`fmus.common.estimator_contract`)
names the inputs an estimator may take and the outputs it must give. An FMU that meets it can
replace any of our estimators in a scenario, and be fed by a recorded log (LogReplay). Each rule
below is checked on the FMU's modelDescription, the last one by running it; a failed rule gives
one line ``<rule>: <what is wrong>``.

======================  ===================================================================
``co-simulation``       FMI 2.0 with a CoSimulation interface
``required-outputs``    ``p_tool_hat[1]``, ``p_tool_hat[2]``: Real outputs
``inputs``              every input is a contract input (name, index within its size), Real
``outputs``             an output with a contract name has the contract's size and is Real
``units``               a declared unit of a contract variable is the contract's (none: SI)
``t_meas``              an input ``t_meas`` starts negative (unstamped until connected)
``runs``                instantiates, initialises with its defaults and start inputs, steps
                        1 s (its default step, else 0.01 s) with a finite ``p_tool_hat``
======================  ===================================================================

The ``runs`` rule executes the FMU's own code, which may be anyone's: it runs in a child process
(its own session, the FMU extracted into a temporary folder the parent removes) with a wall-clock
time limit (``RUN_TIME_LIMIT``, ``--time-limit``), so that an FMU that aborts, dies of a signal
(a segfault) or never returns fails the rule with that cause instead of taking the checker down
or hanging it. An FMI 1.0 FMU is not checked at all (:class:`NotCheckable`).
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:       # (imported where used: the CLI reads this module's constants on every
    from fmus.common import estimator_contract as contract      # command, a run included)

RULES = ("co-simulation", "required-outputs", "inputs", "outputs", "units", "t_meas", "runs")
RUN_TIME = 1.0         # s
RUN_STEP = 0.01        # s, when the FMU has no default step
RUN_TIME_LIMIT = 60.0  # s of wall-clock time for the `runs` rule's child process (--time-limit):
                       # ours take 1-3 s there under load (start-up included), a first JIT
                       # compilation of a third party's kernels can take tens of seconds


class NotCheckable(ValueError):
    """An FMU the contract cannot be checked on at all (FMI 1.0): the CLI's one ``error:`` line."""


def _split(name: str) -> tuple[str, int | None]:
    """``"q_m_meas[2]"`` -> ``("q_m_meas", 2)``; ``"t_meas"`` -> ``("t_meas", None)``."""
    if name.endswith("]") and "[" in name:
        base, index = name[:-1].split("[", 1)
        if index.isdigit():
            return base, int(index)
    return name, None


def _fits(signal: contract.Signal, index: int | None) -> bool:
    return index is None if signal.size is None else (index is not None and 1 <= index <= signal.size)


def check_estimator(path: str | Path, *, run: bool = True,
                    time_limit: float = RUN_TIME_LIMIT) -> list[str]:
    """The failed rules of the contract, one line each (empty: the FMU meets it).

    Parameters
    ----------
    path : str or Path
        The FMU file.
    run : bool
        Also the ``runs`` rule (the FMU's code executed in a child process); without it, the
        rules of the modelDescription only.
    time_limit : float
        Wall-clock seconds the child process of the ``runs`` rule may take (start-up included);
        past them it is killed and the rule fails naming the limit.

    Raises
    ------
    NotCheckable
        An FMI 1.0 FMU (its interface is another standard: no rule applies).
    """
    from fmpy import read_model_description

    from fmus.common import estimator_contract as contract

    from .fmu_store import content_key
    try:
        content_key(Path(path))        # the archive limits (orchestration/archive.py), before any read
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # noqa: BLE001 - not an FMU, a broken zip or XML, beyond the limits
        return [f"co-simulation: cannot read the modelDescription of {path}: {exc}"]
    if str(md.fmiVersion).startswith("1."):
        raise NotCheckable(f"{path}: an FMI {md.fmiVersion} FMU; the estimator contract is FMI 2.0 "
                           "co-simulation (export it as FMI 2.0)")
    failures = []
    if md.fmiVersion != "2.0" or md.coSimulation is None:
        failures.append(f"co-simulation: fmiVersion {md.fmiVersion}, "
                        f"{'a' if md.coSimulation else 'no'} CoSimulation interface (FMI 2.0 "
                        "co-simulation needed)")
    variables = {v.name: v for v in md.modelVariables}
    inputs = {c.name: c for c in contract.INPUTS}
    outputs = {c.name: c for c in contract.REQUIRED_OUTPUTS + contract.OPTIONAL_OUTPUTS}

    missing = [f"{n} ({'not an output' if n in variables else 'missing'})"
               for s in contract.REQUIRED_OUTPUTS for n in s.scalars()
               if n not in variables or variables[n].causality != "output" or variables[n].type != "Real"]
    if missing:
        failures.append("required-outputs: " + ", ".join(missing) + " (a Real output each)")

    bad_inputs = []
    for v in md.modelVariables:
        if v.causality != "input":
            continue
        base, index = _split(v.name)
        if base not in inputs or not _fits(inputs[base], index):
            bad_inputs.append(f"'{v.name}' is not a contract input")
        elif v.type != "Real":
            bad_inputs.append(f"'{v.name}' is {v.type}, not Real")
    for base, s in inputs.items():          # a vector input is taken whole
        present = [n for n in s.scalars() if n in variables and variables[n].causality == "input"]
        if present and len(present) != len(s.scalars()):
            bad_inputs.append(f"'{base}' has {len(present)} of its {s.size} elements")
    if bad_inputs:
        failures.append("inputs: " + "; ".join(bad_inputs) + " (allowed: "
                        + ", ".join(f"{s.name}[{s.size}]" if s.size else s.name for s in contract.INPUTS) + ")")

    bad_outputs = []
    for base, s in outputs.items():
        present = [v for v in md.modelVariables if _split(v.name)[0] == base and v.causality == "output"]
        if present and ({v.name for v in present} != set(s.scalars()) or any(v.type != "Real" for v in present)):
            bad_outputs.append(f"'{base}' must be {len(s.scalars())} Real output(s) "
                               f"{', '.join(s.scalars())}, has {', '.join(v.name for v in present)}")
    if bad_outputs:
        failures.append("outputs: " + "; ".join(bad_outputs))

    bad_units = []
    for v in md.modelVariables:
        base, _ = _split(v.name)
        s = inputs.get(base) if v.causality == "input" else outputs.get(base) if v.causality == "output" else None
        unit = _unit(v)
        if s is not None and unit is not None and unit != s.unit:
            bad_units.append(f"'{v.name}' is in {unit}, the contract's unit is {s.unit}")
    if bad_units:
        failures.append("units: " + "; ".join(bad_units))

    t_meas = variables.get("t_meas")
    if t_meas is not None and t_meas.causality == "input" and not float(t_meas.start or 0.0) < 0.0:
        failures.append(f"t_meas: the input t_meas starts at {t_meas.start}; it must start negative "
                        "(unstamped: the measurements count as taken at the end of each step)")

    if run and md.coSimulation is not None:
        problem = _run_isolated(path, md, [n for s in contract.REQUIRED_OUTPUTS for n in s.scalars()
                                           if n in variables and variables[n].causality == "output"],
                                time_limit)
        if problem:
            failures.append("runs: " + problem)
    return failures


def _unit(v: Any) -> str | None:
    if getattr(v, "unit", None):
        return v.unit
    declared = getattr(v, "declaredType", None)
    return getattr(declared, "unit", None) if declared is not None else None


def _run_isolated(path: str | Path, md: Any, names: list[str], time_limit: float) -> str | None:
    """:func:`_run` in a child process limited to ``time_limit`` wall-clock seconds: why the FMU
    does not run (its failure; an abort, a signal, an exit, or the time limit), None if it does.

    The FMU is extracted here by the FMU store (its checked cache, else a temporary folder
    removed at the end); the child runs in its own session (a Ctrl-C of the terminal goes to
    the checker, which kills it), and on the limit its whole process group is killed (an FMU's
    own children too).
    Its answer comes through a file, not its stdout (which the FMU may write to).
    """
    from . import fmu_store
    fmu_store.run_began()           # (its temporary folder, without a cache, removed at the end)
    try:
        try:
            folder = fmu_store.folder(Path(path))
        except Exception as exc:  # noqa: BLE001 - a broken archive, beyond the limits
            return f"cannot extract {path}: {exc}"
        return _run_child(folder, md, names, time_limit)
    finally:
        fmu_store.run_ended()


def _run_child(folder: str, md: Any, names: list[str], time_limit: float) -> str | None:
    """:func:`_run_isolated` of the FMU extracted in ``folder``."""
    with tempfile.TemporaryDirectory(prefix="flexfusion-check-") as tmp:
        answer = Path(tmp) / "answer.json"
        request = {"fmu": str(folder), "names": names, "answer": str(answer),
                   "step": (md.defaultExperiment.stepSize if md.defaultExperiment is not None
                            and md.defaultExperiment.stepSize else None)}
        with open(Path(tmp) / "stderr.txt", "w+b") as err:
            child = subprocess.Popen([sys.executable, "-P", "-m", "orchestration.contract", "--run-child",
                                      json.dumps(request)], cwd=tmp, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
            t0 = time.monotonic()
            status = None
            try:
                status = child.wait(timeout=time_limit)
            except subprocess.TimeoutExpired:
                pass
            finally:                # also on Ctrl-C of the checker
                if child.returncode is None:
                    _kill_group(child)
            err.seek(max(0, err.seek(0, os.SEEK_END) - 4096))      # its last lines only
            said = [" ".join(line.split()) for line in err.read().decode(errors="replace").splitlines()]
        said = [line for line in said if line]
        last = f"; last line on its stderr: {said[-1][:200]}" if said else ""
        if status is None:
            return (f"did not finish {RUN_TIME:g} s with its defaults and start inputs within the "
                    f"time limit of {time_limit:g} s (wall clock; --time-limit): killed after "
                    f"{time.monotonic() - t0:.1f} s (an endless loop or a hang?){last}")
        if status < 0:
            try:
                name = signal.Signals(-status).name
            except ValueError:
                name = f"signal {-status}"
            cause = {"SIGABRT": "aborted (SIGABRT)", "SIGSEGV": "crashed with a segmentation fault (SIGSEGV)",
                     "SIGBUS": "crashed with a bus error (SIGBUS)", "SIGFPE": "crashed with a "
                     "floating-point exception (SIGFPE)", "SIGKILL": "was killed (SIGKILL; out of memory?)"
                     }.get(name, f"was ended by {name}")
            return f"the FMU's process {cause} while running {RUN_TIME:g} s with its defaults{last}"
        try:
            return json.loads(answer.read_text())["problem"]
        except (OSError, ValueError, KeyError, TypeError):
            return (f"the FMU's process exited with status {status} before it finished running "
                    f"{RUN_TIME:g} s with its defaults{last}")


def _kill_group(child: subprocess.Popen) -> None:  # type: ignore[type-arg]
    """SIGKILL the child's process group (it leads its own session; not yet reaped, so the
    group's id is still its), then reap the child."""
    try:
        os.killpg(child.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    child.wait()


def _run(folder: str | Path, step: float | None, names: list[str]) -> str | None:
    """Why the FMU extracted in ``folder`` does not run 1 s with its defaults and start inputs
    at ``step`` (None: 0.01 s), its outputs ``names`` finite (None: it does). Runs the FMU's
    code in this process: :func:`_run_isolated` calls it in a child."""
    import fmpy
    step = step or RUN_STEP
    log: list[str] = []

    def logger(env: Any, instance: Any, status: int, category: Any, message: bytes) -> None:
        if status > 1 and message:          # discard, error, fatal: the reason of a failure
            log.append(" ".join(message.decode(errors="replace").split()))
    try:
        result = fmpy.simulate_fmu(str(folder), start_time=0.0, stop_time=RUN_TIME, step_size=step,
                                   output_interval=step, output=names, validate=False, logger=logger)
    except Exception as exc:  # noqa: BLE001 - any failure of the FMU is the finding
        return (f"{RUN_TIME:g} s with its defaults and start inputs failed: "
                f"{' '.join(str(exc).split()).rstrip('.')}" + (f"; FMU log: {log[-1]}" if log else ""))
    bad = [n for n in names if not all(math.isfinite(float(x)) for x in result[n])]
    if bad:
        return f"{', '.join(bad)} not finite within {RUN_TIME:g} s with its defaults and start inputs"
    return None


def _child(request: str) -> None:
    """The child process of :func:`_run_isolated`: :func:`_run` of the JSON ``request``, its
    answer written into the request's file."""
    r = json.loads(request)
    problem = _run(r["fmu"], r["step"], r["names"])
    Path(r["answer"]).write_text(json.dumps({"problem": problem}))


def main(paths: list[Path], time_limit: float = RUN_TIME_LIMIT) -> int:
    """Check each FMU (the ``runs`` rule limited to ``time_limit`` wall-clock seconds); print one
    line per failed rule; 0 if all pass, else 2."""
    status = 0
    for path in paths:
        if not Path(path).is_file():
            print(f"error: {path}: no such file", file=sys.stderr)
            status = 2
            continue
        try:
            failures = check_estimator(path, time_limit=time_limit)
        except NotCheckable as exc:
            print(f"error: {exc}", file=sys.stderr)
            status = 2
            continue
        for line in failures:
            print(f"{path}: {line}")
        if failures:
            status = 2
        else:
            print(f"{path}: meets the estimator contract ({len(RULES)} rules)")
    return status


__all__ = ["RULES", "RUN_TIME_LIMIT", "NotCheckable", "check_estimator", "main"]

if __name__ == "__main__" and sys.argv[1:2] == ["--run-child"]:
    _child(sys.argv[2])
