"""What a study scores an estimate against: the reference system by default, the truth as a
second, named column.

The papers could not see their robot's true tool position: they tuned and scored their
estimators against a laser tracker (Henriksson et al. 2009, section IV; Axelsson et al. 2012,
section 5.1; the IMU paper, section 3.3). Our studies do the same by default: the **judge** of
an estimate is the scenario's reference measurement system (a component whose role is
``reference``, :mod:`orchestration.roles`: the ``Tracker`` FMU, ``p_tool_meas`` stamped
``t_meas``; or a replayed log whose column map feeds ``p_tool_meas``, stamped ``t_tool_meas``
when mapped); the plant's truth (``plant.p_tool``) is reported beside it, named as such.

Scoring against a sampled, skewed reference (:func:`aligned`)
--------------------------------------------------------------

* **Its own samples, at its own stamps.** The tracker holds its newest sample between samples;
  a recorded row that repeats a held sample is not a new measurement. Only its fresh samples
  count (where the stamp ``t_meas`` changes), and the estimate is taken at each sample's stamp
  (linearly interpolated between the recorded rows:
  :func:`orchestration.metrics.at_sample_times`). The hold never counts as an error, and a
  tracker slower than the record is not treated as continuous.
* **The skew stays in.** A sample stamped ``t_k`` is the position at ``t_k - skew`` (the
  tracker's clock runs behind the controller's: 1 ms by default). The judge does not know the
  skew, as the papers' authors did not (they synchronised by hand, "which can introduce small
  errors"): at tool speed ``v`` it adds up to ``v * skew`` to every error (0.2 mm at 200 mm/s),
  and a tuner scored this way prefers an estimate that lags by the skew. ``--against truth``
  gives the error the tracker cannot see.
* **Its noise stays in.** ``noise`` (0.02 mm per axis) adds ``noise^2`` per axis to the mean
  squared error; it cannot be tuned away, so it sets a floor of ``sqrt(2) noise`` = 0.028 mm
  to an RMSE against the tracker.
* **The 2009 band-pass on the tracker's samples.** The 3-30 Hz error of Table I is computed on
  the fresh samples (uniform at the tracker's rate, 1 kHz: well above 2 x 30 Hz), not on the
  record's rows. The tracker's white noise has ``noise^2 / (fs / 2)`` per Hz; the band keeps
  ``27 / 500`` of it at 1 kHz: about ``sqrt(2 x 0.054) x 0.02 mm = 0.0066 mm`` rms in the norm,
  which the small 3-30 Hz errors of the 2009 table (0.02-0.04 mm) carry.

:func:`judge` picks the judge of a scenario document: ``against="reference"`` (default) finds
the reference component; ``against="truth"`` the plant's ``p_tool``; an explicit variable
(``truth="comp.var"``, the older ``--truth``) judges against that, and ``against`` then says
what it is (its component's role, :func:`orchestration.roles.against`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: The judges a study can be asked for.
AGAINST = ("reference", "truth")
#: The outputs of a reference measurement system (the Tracker's): the measured tool position and
#: the stamp of the held sample.
REFERENCE_POSITION, REFERENCE_STAMP = "p_tool_meas", "t_meas"
#: The stamps of a recorded reference system in a log (LogReplay; its ``t_meas`` is the sensors').
LOG_REFERENCE_STAMP = "t_tool_meas"
#: The plant's true tool position (the truth judge).
TRUTH_POSITION = "p_tool"


class JudgeError(ValueError):
    """The scenario has no such judge (the message says what to do)."""


@dataclass(frozen=True)
class Judge:
    """What an estimate is scored against.

    ``against`` ``"reference"`` (a reference measurement system), ``"truth"`` (the plant's
    truth), or the role of another component (:func:`orchestration.roles.against`);
    ``component`` its component; ``position`` the variable compared with the estimate (tool
    position, ``comp.var``); ``stamp`` the variable holding each sample's time stamp (None: the
    position is valid at every recorded row).
    """

    against: str
    component: str
    position: str
    stamp: str | None = None
    kind: str = ""

    @property
    def variables(self) -> list[str]:
        """The variables to record."""
        return [self.position] + ([self.stamp] if self.stamp else [])

    def to_json(self) -> dict[str, Any]:
        """``{"against", "component", "fmu", "variable", "stamp"}`` for a study's JSON."""
        return {"against": self.against, "component": self.component, "fmu": self.kind,
                "variable": self.position, "stamp": self.stamp}

    def series(self, run: Any) -> tuple[np.ndarray, np.ndarray | None]:
        """The judge's position and stamps (None) from a run (a mapping of recorded arrays)."""
        return np.asarray(run[self.position]), (None if self.stamp is None else np.asarray(run[self.stamp]))


def _kind(doc: dict[str, Any], component: str) -> str:
    return Path(str(doc["components"][component].get("fmu", ""))).stem


def _role(doc: dict[str, Any], component: str) -> str:
    """The role the component's FMU declares (:mod:`orchestration.fmu_annotation`)."""
    from .fmu_annotation import describe_entry
    return describe_entry(doc, component).role


def log_feeds(columns: str, var: str) -> bool:
    """Whether a LogReplay's column map ``columns`` (``output = column [unit]; ...``) feeds its
    output ``var`` (it declares every contract signal; reading one no column feeds is an error)."""
    entries = str(columns).replace("\n", ";").split(";")
    return var in {e.partition("=")[0].strip().partition("[")[0] for e in entries if "=" in e}


def _parameter(doc: dict[str, Any], component: str, name: str) -> Any:
    """A component's parameter in a document: its own, else its parameter sets' (last wins)."""
    ctab = doc["components"][component]
    value = None
    for sname in ctab.get("parameter_sets", []):
        value = doc.get("parameter_sets", {}).get(sname, {}).get(name, value)
    return ctab.get("parameters", {}).get(name, value)


def _log_reference(doc: dict[str, Any], component: str) -> bool:
    return log_feeds(_parameter(doc, component, "columns") or "", REFERENCE_POSITION)


def reference_components(doc: dict[str, Any]) -> list[str]:
    """The components of a scenario document that measure the tool as a reference system, in
    file order: those whose FMU's role is ``reference`` (the Tracker), and a LogReplay whose
    column map feeds ``p_tool_meas`` (a recorded laser tracker)."""
    return [c for c in doc.get("components", {})
            if _role(doc, c) == "reference" or (_role(doc, c) == "log" and _log_reference(doc, c))]


def truth_components(doc: dict[str, Any]) -> list[str]:
    """The components whose FMU's role is ``plant`` (the truth of the tool position)."""
    return [c for c in doc.get("components", {}) if _role(doc, c) == "plant"]


def judge(doc: dict[str, Any], against: str = "reference", truth: str | None = None) -> Judge:
    """The judge of a scenario document (see the module docstring).

    Parameters
    ----------
    doc
        Scenario document (:func:`orchestration.scenario.scenario_document`).
    against
        ``"reference"`` (default) or ``"truth"``; ignored when ``truth`` is given.
    truth
        An explicit variable ``comp.var`` to judge against (its role decides ``against``; a
        reference component's ``p_tool_meas`` brings its stamp).

    Raises
    ------
    JudgeError
        An unknown ``against``; no reference (or several) in the scenario; no plant.
    """
    if truth is not None:
        comp, _, var = truth.partition(".")
        if comp not in doc.get("components", {}):
            raise JudgeError(f"'{truth}': the scenario has no component '{comp}' (components: "
                             f"{', '.join(doc.get('components', {}))})")
        kind = _kind(doc, comp)
        if var == REFERENCE_POSITION and comp in reference_components(doc):
            return _reference_judge(doc, comp)
        role = _role(doc, comp)
        return Judge("truth" if role in ("plant", "environment") else role, comp, truth, None, kind)
    if against == "reference":
        refs = reference_components(doc)
        if len(refs) != 1:
            raise JudgeError(
                ("the scenario has no reference measurement system (a Tracker component measuring "
                 "the tool) to score against" if not refs else
                 f"the scenario has {len(refs)} reference systems ({', '.join(refs)}): name one with "
                 f"--truth COMP.{REFERENCE_POSITION}")
                + "; add a Tracker measuring the plant's p_tool (as flagship.toml does) or score against "
                  "the plant's truth (--against truth)")
        return _reference_judge(doc, refs[0])
    if against == "truth":
        plants = truth_components(doc)
        if len(plants) != 1:
            raise JudgeError(f"scoring against the truth needs exactly one plant component, found "
                             f"{len(plants)}: name the truth with --truth COMP.VAR")
        return Judge("truth", plants[0], f"{plants[0]}.{TRUTH_POSITION}", None, _kind(doc, plants[0]))
    raise JudgeError(f"unknown judge {against!r} (one of {', '.join(AGAINST)})")


def _reference_judge(doc: dict[str, Any], comp: str) -> Judge:
    """The judge of a reference component: the Tracker's ``p_tool_meas`` at its stamps
    ``t_meas``; a log's ``p_tool_meas`` at its ``t_tool_meas`` when its column map feeds them
    (else at every row: a log without the tracker's stamps)."""
    kind = _kind(doc, comp)
    if _role(doc, comp) == "log":
        stamp = LOG_REFERENCE_STAMP if log_feeds(_parameter(doc, comp, "columns") or "", LOG_REFERENCE_STAMP) else None
    else:
        stamp = REFERENCE_STAMP
    return Judge("reference", comp, f"{comp}.{REFERENCE_POSITION}", stamp and f"{comp}.{stamp}", kind)


def aligned(time: np.ndarray, estimate: np.ndarray, position: np.ndarray, stamp: np.ndarray | None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(times, estimate, judge)`` compared: with ``stamp`` the judge's fresh samples at their
    stamps and the estimate interpolated to them (:func:`orchestration.metrics.at_sample_times`),
    without it every recorded row."""
    if stamp is None:
        return np.asarray(time, dtype=float), np.asarray(estimate, dtype=float), np.asarray(position, dtype=float)
    from .metrics import at_sample_times
    return at_sample_times(time, estimate, position, stamp)


__all__ = ["AGAINST", "Judge", "JudgeError", "judge", "aligned", "reference_components",
           "truth_components", "log_feeds", "LOG_REFERENCE_STAMP", "REFERENCE_POSITION", "REFERENCE_STAMP", "TRUTH_POSITION"]
