"""FlexFusion orchestration: scenarios, the co-simulation master, results, metrics, CLI.

Python API::

    from orchestration import run
    result = run("orchestration/scenarios/flagship.toml", ["scenario.seed=3"], out_dir="results/x")
    result["plant.p_tool"]      # (n, 2) array;  result.time, result.metrics
"""
import os

# OpenBLAS starts a thread per core when numpy loads (about 0.06 s of a run's start-up, here
# with 2 cores) for nothing: the master's and the FMUs' matrices are 2x2 to 10x10, below
# OpenBLAS's threading thresholds, and studies run one process per core. One thread, unless
# the user chose (only read if numpy is not loaded yet).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# The package's names are loaded on first use (PEP 562), not on import: the ``flexfusion``
# command imports ``orchestration.cli`` first, which must be quick so that its Ctrl-C handler
# (``cli.console_main``) is in place before numpy, fmpy and the master load (a Ctrl-C during
# that 0.3-0.7 s ended in a traceback).
_EXPORTS = {"run": "master", "RunError": "master", "Interrupted": "master", "CouplingWarning": "master",
            "Result": "results", "OutputError": "results", "ResultWarning": "results",
            "HonestSignalWarning": "roles", "ScenarioError": "scenario", "load_scenario": "scenario"}

__all__ = ["run", "Result", "ScenarioError", "RunError", "OutputError", "Interrupted", "ResultWarning",
           "CouplingWarning", "HonestSignalWarning", "load_scenario"]


def __getattr__(name: str) -> object:
    """``orchestration.run`` and the other names of ``__all__``, imported on first use."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
