"""FMUs describe themselves: the FlexFusion vendor annotation (docs/fmu_annotation.md) is in
every built FMU's modelDescription and equals its class's declaration; the orchestration reads
a component's role, default search ranges and batched kernel from it, a third party's FMU's too."""
from __future__ import annotations

import importlib
import warnings
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description

from orchestration import HonestSignalWarning, batched, load_scenario, roles
from orchestration.build import _CLASS, FMU_SOURCES, fmu_scripts
from orchestration.fmu_annotation import AnnotationError, ROLES, SelfDescription, describe
from orchestration.study import StudyError
from orchestration.study_tune import default_bounds


def _classes() -> dict[str, type]:
    """Every FMU class of fmus/*/*_fmu.py by model identifier."""
    classes = {}
    for script in fmu_scripts():
        module = importlib.import_module(".".join(script.relative_to(FMU_SOURCES.parent).with_suffix("").parts))
        for name in _CLASS.findall(script.read_text()):
            if hasattr(getattr(module, name), "self_description"):
                classes[name] = getattr(module, name)
    return classes


def test_every_built_fmu_carries_its_class_declaration(every_fmu) -> None:
    classes = _classes()
    assert set(classes) == set(every_fmu)
    for name, cls in classes.items():
        read_model_description(str(every_fmu[name]), validate=True)     # fmpy's schema check
        assert describe(every_fmu[name]) == SelfDescription(**cls.self_description(), annotated=True), name
    # what the orchestration lists said before the FMUs declared it
    assert {n for n, c in classes.items() if c.role == "sensor"} == {"Encoder", "Imu", "ForceTorqueSensor",
                                                                    "Encoder6", "Imu3D"}
    assert describe(every_fmu["Tracker"]).role == "reference"
    assert describe(every_fmu["Tracker3D"]).role == "reference"
    assert {n: c.batched for n, c in classes.items() if c.batched} == \
        {"Encoder": "Encoder", "Imu": "Imu", "EkfAccelerometer": "EkfAccelerometer"}
    assert set(batched.KERNELS) == {c.batched for c in classes.values() if c.batched}
    assert describe(every_fmu["EkfMotor"]).search == {f"lambda{i}": (1e-4, 1e4) for i in range(1, 6)}
    assert describe(every_fmu["ImuEkf"]).search == {"sigma_jerk": (1.0, 1e5), "sigma_alpha": (0.1, 1e4),
                                                    "r_position": (1e-6, 1e-2), "r_orientation": (1e-6, 1e-1)}
    assert describe(every_fmu["Encoder"]).search == {}


def test_the_roles_agree_with_the_fmus() -> None:
    from fmus.common.fmi import ROLES as DECLARABLE
    assert ROLES == DECLARABLE


def _arm_with(sensor_fmu: Path, sensor_input: str) -> dict:
    """The plant under its controller, its motor angles through ``sensor_fmu`` into rigid
    kinematics, a tracker as the reference."""
    return {
        "connections": ["controller.tau_m -> plant.tau_m", "plant.q_m -> controller.q_m",
                        f"plant.q_m -> sensor.{sensor_input}",
                        "plant.p_tool -> tracker.p_tool"],
        "scenario": {"name": "arm", "stop_time": 0.01, "base_step": 0.001, "seed": 1},
        "components": {"controller": {"fmu": "MotionController", "parameters": {"path": "square"}},
                       "plant": {"fmu": "FlexibleRobot2DOF", "parameters": {"p_tool0": [1.2, 0.9]}},
                       "sensor": {"fmu": str(sensor_fmu)},
                       "tracker": {"fmu": "Tracker"}},
    }


def _honest_warnings(doc: dict) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_scenario(doc)
    return [str(w.message) for w in caught if issubclass(w.category, HonestSignalWarning)]


def test_a_third_party_fmu_gets_its_role_and_bounds(fmu_env, third_party_fmus) -> None:
    """A new sensor needs no orchestration edit: the third party's annotated sensor may read the
    plant's motor angles, and the tuner finds its default range; without the annotation the
    same connection is an oracle and there are no default bounds."""
    sensor = third_party_fmus["AnnotatedSensor"]
    assert describe(sensor) == SelfDescription("sensor", None, {"offset": (-0.01, 0.01)}, True)
    doc = _arm_with(sensor, "q_m")
    assert _honest_warnings(doc) == []
    assert default_bounds(doc, "sensor") == {"offset": (-0.01, 0.01)}
    plain = third_party_fmus["ThirdPartyEstimator"]
    assert describe(plain) == SelfDescription()
    doc = _arm_with(plain, "q_m_meas")
    assert len(_honest_warnings(doc)) == 1
    with pytest.raises(StudyError, match="its FMU declares none"):
        default_bounds(doc, "sensor")


def _fmu_with(tmp_path: Path, fmu: Path, component: str) -> Path:
    """A copy of ``fmu`` whose annotation is ``component`` (the <Component> element's text)."""
    out = tmp_path / fmu.name
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "modelDescription.xml":
                text = data.decode()
                start, end = text.index("<Component "), text.index("</Tool>")
                data = (text[:start] + component + text[end:]).encode()
            dst.writestr(info, data)
    return out


@pytest.mark.parametrize("component, match", [
    ('<Component version="1" role="sensr"/>', "role 'sensr' is not one of"),
    ('<Component version="2" role="sensor"/>', "version '2' is not one of 1"),
    ('<Component version="1" role="sensor"><Tune name="offset" low="1" high="-1"/></Component>',
     "needs a name and low < high"),
    ('<Component version="1" role="sensor"><Tune name="offset" low="x" high="1"/></Component>',
     "needs numbers low and high"),
])
def test_a_malformed_annotation_is_refused(third_party_fmus, tmp_path, component, match) -> None:
    bad = _fmu_with(tmp_path, third_party_fmus["AnnotatedSensor"], component)
    with pytest.raises(AnnotationError, match=match):
        describe(bad)
