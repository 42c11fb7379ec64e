"""FlexFusion FMU sources: the math in plain modules, each FMU a thin adapter (``*_fmu.py``)."""
