"""FMU adapter that plays a recorded log (math in :mod:`fmus.robot_plant.log_replay_model`)."""
from __future__ import annotations

import math

from pythonfmu.enums import Fmi2Status

from fmus.common import estimator_contract as contract
from fmus.common.fmi import FlexFusionSlave
from fmus.common.parameters import ParameterError
from fmus.common.sample_time import UNSTAMPED
from fmus.robot_plant.log_replay_model import LogReplayParameters, RecordedLog

#: The outputs: every input an estimator may take (so a log plugs into any estimator that meets
#: the contract), the truth a log recorded in a simulation carries and a reference system's
#: measurement (a real robot's laser tracker), for metrics.
SIGNALS = contract.INPUTS + contract.TRUTH + contract.REFERENCE


class LogReplay(FlexFusionSlave):
    """The columns of a recorded log (CSV or HDF5) as outputs, named as the estimator contract's
    inputs (``q_m_meas``, ``acc_s``, ``dddq_a_ref``, ..., ``t_meas``) and the plant's truth
    (``q_a``, ``p_tool``, ...) and a reference system's measurement (``p_tool_meas`` with its
    stamps ``t_tool_meas``, the judge of a study); the parameter ``columns`` says which column
    feeds which output.

    The outputs at ``t + dt`` are the log at ``t + dt`` (no inputs, no direct feedthrough), after
    initialisation the log at the start time. ``t_meas`` is the time the held values were
    sampled: the mapped stamp column of the held row, else the row's time (hold), or the current
    time (linear interpolation: the values stand for now). An output no column feeds is NaN, and
    reading it (connected or recorded) is an FMI error naming it. The whole log is read and
    checked when initialisation ends: a missing column, a gap, a non-numeric cell or
    non-increasing time is a parameter error naming the file, the column and the row. Without a
    ``log_file`` (the default) every output is 0 and ``t_meas`` unstamped (-1), so that an FMI
    host can run the FMU with its defaults.
    """
    role = "log"

    parameters_class = LogReplayParameters
    description = "Plays a recorded log (CSV, HDF5) as measurement and truth outputs"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        for s in SIGNALS:
            self.output(s.name, s.size, unit=s.unit, description=s.description + " (from the log)",
                        start=math.nan)
        self.log_data: RecordedLog | None = None

    def setup(self, p: LogReplayParameters) -> None:
        if not p.log_file:          # no log: neutral outputs, so that any FMI host can run it bare
            for s in SIGNALS:
                setattr(self, s.name, 0.0) if s.size is None else getattr(self, s.name).fill(0.0)
            self.t_meas = UNSTAMPED
            self.log_data = None
            self.log("no log_file given: every output is 0 and t_meas unstamped", Fmi2Status.warning)
            return
        outputs = {s.name: (s.size, s.unit) for s in SIGNALS}
        self.log_data = RecordedLog(p, outputs, stamp="t_meas")
        # each mapped scalar -> (attribute, index) to write
        self._targets = []
        for m in self.log_data.mappings:
            base, _, index = m.output.partition("[")
            self._targets.append((base, int(index[:-1]) - 1 if index else None))
        self._show(self._time)

    def _show(self, t: float) -> None:
        values, t_sample = self.log_data.sample(t)
        for (base, i), v in zip(self._targets, values.tolist()):
            if i is None:
                setattr(self, base, v)
            else:
                getattr(self, base)[i] = v
        self.t_meas = t_sample

    def step(self, t: float, dt: float) -> None:
        if self.log_data is not None:
            self._show(t + dt)

    def _check_outputs(self, vrs: list[int], values: list[float]) -> None:
        unmapped = [self.vars[vr].name for vr, v in zip(vrs, values)
                    if vr in self._output_vrs and math.isnan(v)]
        if unmapped:
            msg = (f"{self.instance_name}: output '{unmapped[0]}' is read (connected or recorded) "
                   "but no log column feeds it: add it to the parameter 'columns'"
                   + (f" (also {', '.join(unmapped[1:])})" if unmapped[1:] else ""))
            self.log(msg, Fmi2Status.error)
            raise ParameterError(msg)
        super()._check_outputs(vrs, values)
