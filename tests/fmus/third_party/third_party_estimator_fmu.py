"""A third party's estimator, written with plain pythonfmu (nothing of FlexFusion): tool position
by rigid forward kinematics of the measured motor angles. It meets the estimator contract
(docs/estimator_contract.md); tests/test_contract.py checks it and runs it in a scenario."""
import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class ThirdPartyEstimator(Fmi2Slave):
    author = "a third party"
    description = "Rigid forward kinematics of the motor angles (contract test toy)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.q = [0.0, 0.0]                 # measured motor angles, motor side (rad)
        self.p = [0.0, 0.0]                 # tool position, world x and z (m)
        self.l1, self.l2, self.r1, self.r2 = 0.9, 1.2, 200.0, 160.0
        for i in range(2):
            self.register_variable(Real(f"q_m_meas[{i + 1}]", causality=Fmi2Causality.input,
                                        getter=lambda i=i: self.q[i],
                                        setter=lambda v, i=i: self.q.__setitem__(i, v)))
            self.register_variable(Real(f"p_tool_hat[{i + 1}]", causality=Fmi2Causality.output,
                                        initial=Fmi2Initial.exact,
                                        getter=lambda i=i: self.p[i]))
        for name in ("l1", "l2"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        self._update()

    def _update(self):
        a1, a2 = self.q[0] / self.r1, self.q[1] / self.r2
        self.p = [self.l1 * math.cos(a1) + self.l2 * math.cos(a1 + a2),
                  self.l1 * math.sin(a1) + self.l2 * math.sin(a1 + a2)]

    def exit_initialization_mode(self):
        self._update()

    def do_step(self, current_time, step_size):
        self._update()
        return True
