"""An estimator that breaks the contract (plain pythonfmu): it reads the plant's true tool
position, has no p_tool_hat, a one-element q_a_hat, and fails after 0.5 s."""
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Real


class LeakyEstimator(Fmi2Slave):
    author = "a third party"
    description = "Breaks the estimator contract (contract test toy)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = {"q_m_meas[1]": 0.0, "p_tool[1]": 0.0, "p_tool[2]": 0.0, "t_meas": 0.0,
                       "p_hat[1]": 0.0, "q_a_hat[1]": 0.0}
        for name in self.values:
            causality = Fmi2Causality.output if "hat" in name else Fmi2Causality.input
            self.register_variable(Real(name, causality=causality, initial=Fmi2Initial.exact
                                        if "hat" in name else None,
                                        getter=lambda n=name: self.values[n],
                                        setter=None if "hat" in name else
                                        (lambda v, n=name: self.values.__setitem__(n, v))))

    def do_step(self, current_time, step_size):
        if current_time >= 0.5:
            raise RuntimeError("diverged")
        self.values["p_hat[1]"] = self.values["p_tool[1]"]
        return True
