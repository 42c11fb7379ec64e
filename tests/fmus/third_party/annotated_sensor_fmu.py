"""A third party's sensor, written with plain pythonfmu (nothing of FlexFusion): motor angles
plus a constant offset. It says what it is with the FlexFusion vendor annotation
(docs/fmu_annotation.md), written by hand into its modelDescription: a sensor (so it may read
the plant's truth) whose ``offset`` the tuner searches in [-0.01, 0.01] by default.
tests/test_fmu_annotation.py checks the orchestration takes both from it."""
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class AnnotatedSensor(Fmi2Slave):
    author = "a third party"
    description = "Motor angles plus an offset (vendor-annotation test toy)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.q = [0.0, 0.0]                 # motor angles (rad)
        self.offset = 0.0                   # added to each (rad)
        for i in range(2):
            self.register_variable(Real(f"q_m[{i + 1}]", causality=Fmi2Causality.input,
                                        getter=lambda i=i: self.q[i],
                                        setter=lambda v, i=i: self.q.__setitem__(i, v)))
            self.register_variable(Real(f"q_m_meas[{i + 1}]", causality=Fmi2Causality.output,
                                        initial=Fmi2Initial.exact,
                                        getter=lambda i=i: self.q[i] + self.offset))
        self.register_variable(Real("offset", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))

    def to_xml(self, model_options=dict()):  # noqa: B006 - pythonfmu's signature
        root = super().to_xml(model_options)
        annotations = Element("VendorAnnotations")
        tool = SubElement(annotations, "Tool", name="flexfusion")
        comp = SubElement(tool, "Component", version="1", role="sensor")
        SubElement(comp, "Tune", name="offset", low="-0.01", high="0.01")
        root.insert(list(root).index(root.find("ModelVariables")), annotations)
        return root

    def do_step(self, current_time, step_size):
        return True
