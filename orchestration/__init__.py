"""FlexFusion orchestration: scenarios, the co-simulation master, results, metrics, CLI.

Python API::

    from orchestration import run
    result = run("orchestration/scenarios/flagship.toml", ["scenario.seed=3"], out_dir="results/x")
    result["plant.p_tool"]      # (n, 2) array;  result.time, result.metrics
"""
from .master import CouplingWarning, RunError, run
from .results import Result
from .roles import HonestSignalWarning
from .scenario import ScenarioError, load_scenario

__all__ = ["run", "Result", "ScenarioError", "RunError", "CouplingWarning", "HonestSignalWarning",
           "load_scenario"]
