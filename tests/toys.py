"""The toy FMUs of tests/fmus, the scenarios several test modules run on them, and a driver of
an FMU class in this process (:class:`InProcess`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.linalg import expm

TOYS = Path(__file__).parent / "fmus"


def toml_document(doc: dict) -> str:
    """A whole scenario document as TOML (a line of an inline table per top-level key)."""
    from orchestration.scenario import toml_value
    return "".join(f"{k} = {toml_value(v)}\n" for k, v in doc.items())


def with_third_party(scenario: Path | dict, fmus: dict[str, Path], path: Path, name: str = "toy",
                     model: str = "ThirdPartyEstimator", source: str = "encoder.q_m_meas",
                     overrides: tuple[str, ...] = ()) -> Path:
    """``scenario`` (self-contained) with a third-party estimator ``name`` (the FMU ``model`` of
    :func:`conftest.third_party_fmus`) fed the motor angles of ``source``, written to ``path``."""
    from orchestration.scenario import scenario_document
    doc = scenario_document(scenario, overrides)
    doc["components"][name] = {"fmu": str(fmus[model])}
    if source:
        doc["connections"] += [f"{source} -> {name}.q_m_meas"]
    path.write_text(toml_document(doc))
    return path


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    """A scenario file with ``text`` in ``tmp_path``."""
    p = tmp_path / name
    p.write_text(text)
    return p


# two coupled mass-springs, with an analytic solution
KA, KB, KC, MA, MB = 4.0, 1.0, 2.0, 1.0, 2.0
MASS_SPRING = f"""
connections = ["a.x -> b.x_other", "b.x -> a.x_other"]
[scenario]
name = "coupled"
stop_time = 2.0
base_step = 0.01
[components.a]
fmu = "MassSpring"
parameters = {{ m = {MA}, k = {KA}, kc = {KC}, x0 = 1.0 }}
[components.b]
fmu = "MassSpring"
parameters = {{ m = {MB}, k = {KB}, kc = {KC}, v0 = 0.5 }}
[record]
variables = ["a.x", "b.x"]
"""


def analytic(t: np.ndarray) -> np.ndarray:
    """Positions of the two coupled masses: x'' = -M^-1 K x, exact (matrix exponential)."""
    K = np.array([[KA + KC, -KC], [-KC, KB + KC]])
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.diag([1 / MA, 1 / MB]) @ K, np.zeros((2, 2))]])
    z0 = np.array([1.0, 0.0, 0.0, 0.5])
    return np.array([(expm(A * ti) @ z0)[:2] for ti in t])


# a Failing component (its `mode` filled in by the test) at t = 0.05 s, feeding a gain
FAILING = """
connections = ["bad.y -> g.u"]
[scenario]
stop_time = 0.1
base_step = 0.001
[components.bad]
fmu = "Failing"
parameters = {{ fail_at = 0.05, mode = "{mode}" }}
[components.g]
fmu = "Gain"
"""


class InProcess:
    """An FMU class instance driven through its FMI methods by variable name."""

    def __init__(self, cls, start: float = 0.0, **params) -> None:
        self.s = cls(instance_name="t")
        self.vr = {v.name: vr for vr, v in self.s.vars.items()}
        self.s.setup_experiment(start, None, None)
        self.s.enter_initialization_mode()
        for k, v in params.items():
            self.set(**{k: v}) if isinstance(v, (tuple, list)) else setattr(self.s, k, v)
        self.t = start

    def names(self, name: str, size: int | None) -> list[str]:
        return [name] if size is None else [f"{name}[{i + 1}]" for i in range(size)]

    def set(self, **values) -> None:
        for k, v in values.items():
            v = np.atleast_1d(np.asarray(v, float))
            names = [k] if k in self.vr else self.names(k, v.size)
            self.s.set_real([self.vr[n] for n in names], list(map(float, v)))

    def get(self, name: str, size: int | None = None):
        values = self.s.get_real([self.vr[n] for n in self.names(name, size)])
        return values[0] if size is None else np.array(values)

    def init(self) -> None:
        self.s.exit_initialization_mode()

    def step(self, h: float = 1e-3) -> None:
        assert self.s.do_step(self.t, h)
        self.t += h
