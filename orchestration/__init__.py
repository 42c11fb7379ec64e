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

from .master import CouplingWarning, Interrupted, RunError, run
from .results import OutputError, Result, ResultWarning
from .roles import HonestSignalWarning
from .scenario import ScenarioError, load_scenario

__all__ = ["run", "Result", "ScenarioError", "RunError", "OutputError", "Interrupted", "ResultWarning",
           "CouplingWarning", "HonestSignalWarning", "load_scenario"]
