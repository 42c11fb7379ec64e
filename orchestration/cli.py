"""The ``flexfusion`` command line: build, run, plot, export-ssp, check-estimator, study, cache.

Every error a user can cause ends in one line ``error: ...`` on stderr and exit status 2. A run
stopped by SIGINT (Ctrl-C) or SIGTERM ends with one line ``error: interrupted ...`` and exit
status 128 + the signal number (130, 143: the shell's rule for a process ended by a signal),
its results up to then on disk (``run.json`` status ``interrupted``).
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

EXIT_USER_ERROR = 2

log = logging.getLogger(__name__)

EXAMPLES = """examples:
  flexfusion build                                    # build every FMU into dist/fmus
  flexfusion run orchestration/scenarios/flagship.toml --stop-time 1 --out results/quick
  flexfusion run orchestration/scenarios/flagship.toml --set ekf.r_acc=1e-3 --set scenario.seed=7 -q
  flexfusion plot results/quick                       # variables.png (and tool_path.png)
  flexfusion study KIND --help                        # the studies: flexfusion study --help
"""


def version() -> str:
    """The installed ``flexfusion`` distribution's version (importlib.metadata)."""
    from importlib import metadata
    try:
        return metadata.version("flexfusion")
    except metadata.PackageNotFoundError:
        return "unknown (the flexfusion distribution is not installed)"


class _Version(argparse.Action):
    """``--version``: the distribution's version, looked up only when asked (importing and
    scanning importlib.metadata took 0.1 s under load, which every command would pay)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: Any, values: Any,
                 option_string: str | None = None) -> None:
        print(f"{parser.prog} {version()}")
        parser.exit()


def _log_level(args: argparse.Namespace) -> int:
    """``--log-level`` if given, else WARNING moved down by each ``-v`` (INFO, DEBUG) and up by
    each ``-q`` (ERROR, CRITICAL)."""
    if getattr(args, "log_level", None):
        return int(getattr(logging, args.log_level))
    steps = getattr(args, "verbose", 0) - getattr(args, "quiet", 0)
    return min(max(logging.WARNING - 10 * steps, logging.DEBUG), logging.CRITICAL)


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """A handler writing to ``sys.stderr`` as it is at each message (a replaced stderr, as
    pytest's capture or a caller's redirect, gets the messages)."""

    @property                                       # type: ignore[override]
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def configure_logging(level: int) -> None:
    """The ``orchestration`` loggers at ``level``, to stderr as ``level: message`` lines (one
    handler, added once)."""
    package = logging.getLogger(__name__.rpartition(".")[0])
    package.setLevel(level)
    if not any(isinstance(h, _StderrHandler) for h in package.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
        package.addHandler(handler)
        package.propagate = False


def _error(message: str) -> int:
    print("error: " + " ".join(str(message).split()), file=sys.stderr)
    return EXIT_USER_ERROR


def _output_folder_error(exc: OSError, out: Any) -> int:
    return _error(f"cannot use the output folder {exc.filename or out}: {exc.strerror or exc}")


def _show_warning(message: Any, category: Any, filename: str, lineno: int, file: Any = None,
                  line: Any = None) -> None:
    if log.isEnabledFor(logging.WARNING):           # -q (ERROR) hides them
        print(f"warning: {message}", file=sys.stderr)


@contextmanager
def loaded(path: Path, overrides: list[str] | tuple[str, ...] = ()) -> Iterator[Any]:
    """The scenario of a TOML file, or of an SSP package (``.ssp``, ``.ssd``), whose FMUs exist
    while the context lasts."""
    if path.suffix.lower() in (".ssp", ".ssd"):
        from .ssp import load_ssp, opened
        with opened(path) as ssd:
            yield load_ssp(path, ssd, overrides)
    else:
        from .scenario import load_scenario
        yield load_scenario(path, overrides)


def cmd_run(args: argparse.Namespace) -> int:
    from . import fork
    from .master import Interrupted, RunError, run, stop_on_signals
    from .results import OutputError
    from .scenario import ScenarioError

    errors: tuple[type[BaseException], ...] = (ScenarioError, RunError, OutputError, Interrupted)
    if args.forks is not None:
        from .study import StudyError, open_executor   # (multiprocessing: only for the forks)
        errors += (StudyError,)
        if args.save_state_at is None or args.state_out is not None or args.from_state is not None:
            return _error("--forks N goes with --save-state-at T (the state is written into the "
                          "output folder), not with --state-out or --from-state")
        if args.forks < 1:
            return _error(f"--forks {args.forks}: at least one fork")
        if args.scenario.suffix.lower() in (".ssp", ".ssd"):
            return _error("--forks needs a scenario file (TOML), not an SSP package")
    elif (args.save_state_at is None) != (args.state_out is None):
        return _error("--save-state-at T and --state-out FILE go together")
    if args.from_state is not None and args.save_state_at is not None:
        return _error("--from-state and --save-state-at cannot be combined")
    if args.forks is None and (args.workers is not None or args.scheduler is not None):
        return _error("--workers and --scheduler go with --forks N (the forks run on them)")
    try:
        with stop_on_signals(), loaded(args.scenario, args.set or ()) as scenario:
            log.info("scenario %s from %s: stop_time %g s, base step %g s, seed %d, overrides %s",
                     scenario.name, args.scenario, scenario.stop_time, scenario.base_step,
                     scenario.seed, list(args.set or ()) or "none")
            if args.forks is not None:      # fork i: scenario.seed = seed + i (fork.monte_carlo)
                out = args.out or Path("results") / f"{scenario.name}-forks"
                seeds = range(scenario.seed + 1, scenario.seed + 1 + args.forks)
                with open_executor(args.workers, args.scheduler) as ex:
                    forks = fork.monte_carlo(args.scenario, args.save_state_at, seeds, args.set or (), out,
                                             executor=ex, progress=not args.no_progress)
            else:
                out = args.out or Path("results") / scenario.name
                hook = (fork.from_state(scenario, args.from_state) if args.from_state is not None else
                        fork.saving(scenario, args.save_state_at, args.state_out)
                        if args.save_state_at is not None else None)
                result = run(scenario, out_dir=out, progress=not args.no_progress, force=args.force,
                             hook=hook)
    except errors as exc:
        msg = str(exc)
        out_dir = getattr(exc, "out_dir", None)
        if out_dir is not None:
            msg += f" (results up to then in {out_dir})"
        _error(msg)
        return 128 + exc.signum if isinstance(exc, Interrupted) else EXIT_USER_ERROR
    except OSError as exc:          # the output folder: not creatable, not writable
        return _output_folder_error(exc, args.out)
    if args.forks is not None:       # the metrics: mean +- standard deviation over the forks
        import numpy as np
        print(f"{scenario.name}: warm-up in {out / 'warmup'}, state at t = {args.save_state_at:g} s "
              f"in {out / 'state.json'}")
        for seed, result in zip(seeds, forks):
            print(f"  fork scenario.seed={seed}: {len(result.time)} rows in {result.out_dir}")
        for name in forks[0].metrics:       # each fork's metrics are over its rows, from T on
            values = np.array([f.metrics[name] for f in forks])
            spread = f" +- {values.std(ddof=1):.2g}" if len(values) > 1 else ""
            unit = forks[0].metric_units.get(name, "")
            print(f"  {name:<32} {values.mean():.6g}{spread} {unit if unit != '1' else ''}".rstrip())
        return 0
    print(f"{scenario.name}: {len(result.time)} rows in {result.out_dir}")
    if args.state_out is not None:
        print(f"  state at t = {args.save_state_at:g} s in {args.state_out}")
    for name, value in result.metrics.items():
        unit = result.metric_units.get(name, "")
        print(f"  {name:<32} {value:.6g} {unit if unit != '1' else ''}".rstrip())   # "1": no unit
    return 0


def _variables_figure(result: Any, path: Path, max_vars: int = 40) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = result.variables()[:max_vars]
    n = max(len(names), 1)
    fig, axes = plt.subplots(n, 1, figsize=(9, 1.9 * n + 0.6), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        y = result[name]
        y = y.reshape(len(y), -1)
        for j in range(y.shape[1]):
            ax.plot(result.time, y[:, j], lw=0.9, label=f"[{j + 1}]" if y.shape[1] > 1 else None)
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
        if y.shape[1] > 1:
            ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _tool_figure(result: Any, path: Path, truth: str, estimates: list[str]) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    p = result[truth]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ax1.plot(p[:, 0], p[:, 1], "k", lw=1.5, label=truth)
    for est in estimates:
        q = result[est]
        ax1.plot(q[:, 0], q[:, 1], lw=0.9, label=est)
        ax2.plot(result.time, 1e3 * np.linalg.norm(q - p, axis=1), lw=0.9, label=est)
    ax1.set_xlabel("x (m)")
    ax1.set_ylabel("z (m)")
    ax1.set_title("tool path (x-z plane)")
    ax1.axis("equal")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("|p_hat - p| (mm)")
    ax2.set_title("tool position error")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(out_dir: Path) -> list[Path]:
    """PNG plots of a run folder: every recorded variable over time (``variables.png``) and,
    when the run recorded ``plant.p_tool`` and some ``*.p_tool_hat``, the tool path with the
    estimates and the error norm over time (``tool_path.png``)."""
    from .results import Result

    result = Result.load(out_dir)
    written = [_variables_figure(result, Path(out_dir) / "variables.png")]
    variables = result.variables()
    truth = "plant.p_tool"
    estimates = [v for v in variables if v.endswith(".p_tool_hat")]
    if truth in variables and estimates and result[truth].ndim == 2 and result[truth].shape[1] >= 2:
        written.append(_tool_figure(result, Path(out_dir) / "tool_path.png", truth, estimates))
    return written


def cmd_plot(args: argparse.Namespace) -> int:
    out = Path(args.dir)
    if not out.is_dir():
        return _error(f"{out}: no such run folder")
    try:
        written = plot_run(out)
    except (OSError, ValueError, KeyError) as exc:     # OSError: also a full disk
        return _error(f"{out}: cannot plot: {exc}")
    for p in written:
        print(p)
    return 0


def export_ssp(scenario_path: Path, out: Path, overrides: list[str] | tuple[str, ...] = (),
               host: str = "libcosim") -> Path:
    """Write a scenario as an SSP package (see :mod:`orchestration.ssp`)."""
    from .scenario import load_scenario
    from .ssp import export_scenario

    return export_scenario(load_scenario(scenario_path, overrides), out, host)


def cmd_export_ssp(args: argparse.Namespace) -> int:
    from .scenario import ScenarioError
    try:
        path = export_ssp(Path(args.scenario), Path(args.output), args.set or (), args.host)
    except ScenarioError as exc:
        return _error(str(exc))
    except OSError as exc:
        return _error(f"cannot write {args.output}: {exc}")
    print(path)
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    """``flexfusion cache info|clear`` (:mod:`orchestration.caches`)."""
    from .caches import main as caches_main
    try:
        return caches_main(args.action)
    except OSError as exc:
        return _error(f"cannot read the cache: {exc.strerror or exc}: {exc.filename or ''}")


def cmd_check_estimator(args: argparse.Namespace) -> int:
    from .contract import main as check
    if not args.time_limit > 0:         # (also NaN)
        return _error(f"--time-limit {args.time_limit:g}: a positive number of seconds")
    return check(args.fmus, time_limit=args.time_limit)


def add_verbosity_arguments(parser: argparse.ArgumentParser) -> None:
    """``-v``, ``-q`` and ``--log-level`` on ``parser``, each absent from the namespace unless
    given (so a sub-command's parser keeps what the main parser read)."""
    parser.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                        help="more log output (-v: info, -vv: debug)")
    parser.add_argument("-q", "--quiet", action="count", default=argparse.SUPPRESS,
                        help="errors only: no progress bar, no warnings")
    parser.add_argument("--log-level", type=str.upper, default=argparse.SUPPRESS,
                        choices=["DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"],
                        help="the log level (overrides -v/-q; default WARNING)")


def main(argv: list[str] | None = None) -> int:
    from .contract import RUN_TIME_LIMIT
    from .ssp import HOSTS

    # -v/-q/--log-level before or after the sub-command (SUPPRESS: a sub-command's parser does
    # not reset what the main parser read; no set_defaults, which would change the shared actions)
    common = argparse.ArgumentParser(add_help=False)
    add_verbosity_arguments(common)
    parser = argparse.ArgumentParser(prog="flexfusion", description=__doc__.splitlines()[0],
                                     parents=[common], epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version, help="show the version and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("build", help="build and validate every FMU into dist/fmus", add_help=False)

    p_run = sub.add_parser("run", help="run a scenario: results.csv, metrics.json, run.json",
                           parents=[common], formatter_class=argparse.RawDescriptionHelpFormatter,
                           epilog="examples:\n"
                           "  flexfusion run SCENARIO.toml --stop-time 2 --out /tmp/r --force\n"
                           "  flexfusion run SCENARIO.toml --set ekf.r_acc=1e-3 --set scenario.seed=3 -v\n"
                           "  flexfusion run SCENARIO.toml --save-state-at 1 --forks 8 --workers 2\n")
    p_run.add_argument("scenario", type=Path, help="scenario file (TOML), or an SSP package (.ssp, .ssd)")
    p_run.add_argument("--set", action="append", metavar="COMP.PARAM=VALUE",
                       help="override a parameter (repeatable); also scenario.seed=N, scenario.stop_time=T")
    p_run.add_argument("--stop-time", metavar="T",
                       help="the run's stop time (s): the same as --set scenario.stop_time=T, "
                            "given after every --set")
    p_run.add_argument("--out", type=Path, help="output folder (default results/<scenario name>); "
                       "one run at a time owns it")
    p_run.add_argument("--force", action="store_true",
                       help="replace the results of an earlier run in the output folder")
    p_run.add_argument("--no-progress", action="store_true", help="no progress bar")
    p_run.add_argument("--save-state-at", type=float, metavar="T",
                       help="save the whole co-simulation's state at time T (s) into --state-out "
                            "(with --forks: into the output folder)")
    p_run.add_argument("--state-out", type=Path, metavar="FILE", help="the state file to write")
    p_run.add_argument("--from-state", type=Path, metavar="FILE",
                       help="start from a saved state (results from its time on); a fork may "
                            "change stop_time, record, metrics and tunable parameters only (a new "
                            "scenario.seed or sensor seed reseeds the sensors)")
    p_run.add_argument("--forks", type=int, metavar="N",
                       help="with --save-state-at T: a Monte Carlo after a common warm-up, N forks "
                            "from the state at T with scenario.seed = seed+1 .. seed+N, into "
                            "--out (default results/<name>-forks): state.json, warmup/, seed-<s>/")
    p_run.add_argument("--workers", type=int, metavar="K",
                       help="with --forks: local worker processes the forks run on (default: the "
                            "number of cores)")
    p_run.add_argument("--scheduler", metavar="ADDRESS",
                       help="with --forks: run them on a Dask cluster (tcp://host:port, or 'local'; "
                            "its workers must see --out)")

    p_plot = sub.add_parser("plot", help="PNG plots of a run folder", parents=[common])
    p_plot.add_argument("dir", type=Path, help="a run folder (flexfusion run --out)")

    p_ssp = sub.add_parser("export-ssp", help="export a scenario as an SSP package", parents=[common])
    p_ssp.add_argument("scenario", type=Path, help="scenario file (TOML)")
    p_ssp.add_argument("-o", "--output", required=True, type=Path, help="the .ssp file to write")
    p_ssp.add_argument("--set", action="append", metavar="COMP.PARAM=VALUE", help="override a parameter")
    p_ssp.add_argument("--host", choices=HOSTS, default=HOSTS[0],
                       help="the engine's annotations: libcosim (default) gives each component with "
                            "its own step an osp:StepSizeHint, which OMSimulator rejects")

    p_cache = sub.add_parser("cache", help="the caches (extracted FMUs, compiled code, parsed model "
                             "descriptions): info lists them, clear removes what no running process uses")
    p_cache.add_argument("action", choices=("info", "clear"))

    p_check = sub.add_parser("check-estimator", help="check FMUs against the estimator contract "
                             "(docs/estimator_contract.md): one line per failed rule, exit 2 if any")
    p_check.add_argument("fmus", type=Path, nargs="+", metavar="FILE.fmu")
    p_check.add_argument("--time-limit", type=float, metavar="SECONDS", default=RUN_TIME_LIMIT,
                         help="wall-clock limit of the 'runs' rule, which runs the FMU's code in "
                              "a child process (default %(default)g s); past it the rule fails")

    p_study = sub.add_parser("study", help="studies: Monte Carlo, tuning, robustness, ...", parents=[common])
    kinds = p_study.add_subparsers(dest="study", required=True, metavar="KIND")
    argv = sys.argv[1:] if argv is None else list(argv)
    if next((a for a in argv if not a.startswith("-")), None) == "study":
        # only then: the study modules import the working tree's `fmus` (models, CRLB), which a
        # run must not (it runs the FMUs' own bundled copies)
        for module in study_modules():
            module.register(kinds)
        for kind in kinds.choices.values():       # -v/-q/--log-level after `study KIND` too
            add_verbosity_arguments(kind)

    args, rest = parser.parse_known_args(argv)
    level = _log_level(args)
    configure_logging(level)
    if level > logging.WARNING and hasattr(args, "no_progress"):
        args.no_progress = True          # -q: no progress bar
    if args.command == "build":
        from orchestration import build
        return build.main(rest)
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    args.argv = argv                     # recorded in a study folder's status.json
    if args.command == "run" and args.stop_time is not None:    # (study robustness has its own)
        args.set = [*(args.set or ()), f"scenario.stop_time={args.stop_time}"]
    workers = getattr(args, "workers", None)
    if workers is not None and workers < 1:      # before anything is loaded or computed
        return _error(f"--workers must be at least 1, not {workers}")
    handlers = {"run": cmd_run, "plot": cmd_plot, "export-ssp": cmd_export_ssp, "study": cmd_study,
                "check-estimator": cmd_check_estimator, "cache": cmd_cache}
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        return handlers[args.command](args)


def study_modules() -> list[Any]:
    """The ``orchestration.study_<kind>`` modules: each adds its sub-command with
    ``register(subparsers)``, whose ``func(args)`` returns the exit status."""
    import importlib
    import pkgutil

    from orchestration import __path__ as package_path
    names = sorted(m.name for m in pkgutil.iter_modules(package_path) if m.name.startswith("study_"))
    modules = [importlib.import_module(f"orchestration.{name}") for name in names]
    return [m for m in modules if hasattr(m, "register")]


def cmd_study(args: argparse.Namespace) -> int:
    """A study in its ``--out`` folder (:class:`orchestration.study.StudyFolder`): checked and
    locked before any run, each finished run kept, ``--resume`` reuses them."""
    from .master import RunError
    from .results import OutputError
    from .scenario import ScenarioError
    from .study import StudyError, StudyInterrupted, study_folder

    command = " ".join(["flexfusion", *getattr(args, "argv", [])])
    folder = None
    try:
        with study_folder(args.out, resume=args.resume, command=command) as folder:
            return args.func(args)
    except StudyInterrupted as exc:
        kept = (f"{folder.stored()} finished runs are kept in {args.out}; add --resume to continue"
                if folder else "no run had started")
        print(f"error: interrupted by {exc}: {kept}", file=sys.stderr)
        return 128 + exc.signum
    except (StudyError, ScenarioError, RunError, OutputError) as exc:
        return _error(str(exc))
    except OSError as exc:
        return _output_folder_error(exc, args.out)


def console_main() -> None:
    """The ``flexfusion`` console script (Ctrl-C outside a run: one line, no traceback)."""
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        _error("interrupted")
        sys.exit(128 + signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
