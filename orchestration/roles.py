"""What each component is, by FMU model identifier, and the honest-signals rule built on it.

The plant (and its environment) is the truth; everything else must see it only through
sensors. A connection from a truth output (or a recorded truth that a LogReplay plays) into
anything but a sensor, the environment, the plant itself or the reference measurement system
is an oracle: :func:`dishonest_connections`
finds them, and the scenario loader warns (:class:`HonestSignalWarning`) unless the scenario
lists the connection under ``oracles``. The one exception is the drive's own motor feedback:
the MotionController may read the plant's ``q_m`` (an ideal encoder; it has no speed input, it
forms the speed from the angle). Every shipped scenario connects an Encoder's ``q_m_meas``
instead (``tests/test_honest_signals.py``).

A component's role is what its FMU declares in its modelDescription's FlexFusion vendor
annotation (:mod:`orchestration.fmu_annotation`, docs/fmu_annotation.md); an FMU without one (a
user's own) counts as an estimator/controller.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

from .fmu_annotation import describe

if TYPE_CHECKING:
    from .scenario import Component, Connection

#: Roles whose outputs are the truth.
TRUTH_ROLES = frozenset({"plant", "environment"})
#: Roles that may take a truth output as input.
TRUTH_READERS = frozenset({"plant", "environment", "sensor", "reference"})
#: Outputs of the LogReplay that carry a recorded truth, for metrics only: the names of
#: fmus.common.estimator_contract.TRUTH (not imported: a run never imports the working tree's
#: fmus; tests/test_log_replay.py checks they agree).
LOG_TRUTH = frozenset({"q_a", "dq_a", "ddq_a", "p_tool"})
#: The drive's own motor feedback: these plant outputs may feed the MotionController.
DRIVE_FEEDBACK = frozenset({"q_m"})


class HonestSignalWarning(UserWarning):
    """A plant truth output feeds an estimator or controller (not marked as an oracle)."""


def role(component: "Component") -> str:
    """``plant``, ``environment``, ``sensor``, ``reference``, ``controller``, ``log`` (a
    recorded log's player) or ``estimator`` (also for an FMU that does not say): what the
    component's FMU declares (:func:`orchestration.fmu_annotation.describe`)."""
    return describe(component.fmu).role


def against(component: "Component") -> str:
    """What a metric compares with when its ``truth`` variable comes from ``component``:
    ``"truth"`` (plant or environment), ``"reference"`` (the reference measurement system),
    ``"log"`` (a column of a recorded log: a simulation's truth or a real robot's reference), or
    the component's role otherwise (e.g. ``"controller"`` for a tracking error)."""
    r = role(component)
    return "truth" if r in TRUTH_ROLES else r


def is_honest(connection: "Connection", components: dict[str, "Component"]) -> bool:
    """Whether a connection obeys the honest-signals rule (see the module docstring)."""
    src, dst = components[connection.src], components[connection.dst]
    truth = role(src) in TRUTH_ROLES or (role(src) == "log" and connection.src_var in LOG_TRUTH)
    if not truth or role(dst) in TRUTH_READERS:
        return True
    return (role(src) == "plant" and connection.src_var in DRIVE_FEEDBACK
            and dst.model_identifier == "MotionController")


def dishonest_connections(connections: Iterable["Connection"], components: dict[str, "Component"]
                          ) -> list["Connection"]:
    """The connections that feed a truth output into an estimator or a controller."""
    return [c for c in connections if not is_honest(c, components)]


__all__ = ["TRUTH_ROLES", "TRUTH_READERS", "LOG_TRUTH", "DRIVE_FEEDBACK", "HonestSignalWarning",
           "role", "against", "is_honest", "dishonest_connections"]
