"""FlexFusion orchestration: scenarios, the co-simulation master, results, metrics, CLI.

Python API::

    from orchestration import run
    result = run("orchestration/scenarios/flagship.toml", ["scenario.seed=3"], out_dir="results/x")
    result["plant.p_tool"]      # (n, 2) array;  result.time, result.metrics
"""
from .master import CouplingWarning, Interrupted, RunError, run
from .results import OutputError, Result, ResultWarning
from .roles import HonestSignalWarning
from .scenario import ScenarioError, load_scenario

__all__ = ["run", "Result", "ScenarioError", "RunError", "OutputError", "Interrupted", "ResultWarning",
           "CouplingWarning", "HonestSignalWarning", "load_scenario"]
