"""Scenario loading: format, includes, seeds, overrides and every validation error."""
from __future__ import annotations


import numpy as np
import pytest

from orchestration.scenario import (ScenarioError, copy_document, load_scenario, merge_include,
                                    override_strings, parse_override, parse_value, stable_seed,
                                    toml_value)
from toys import write


pytestmark = pytest.mark.usefixtures("toy_fmus")


BASE = """
connections = ["src.y -> g.u", "src.ys -> g.uv"]
[scenario]
name = "toy"
description = "a toy"
stop_time = 0.1
base_step = 0.001
seed = 7
[components.src]
fmu = "Source"
step = 0.002
[components.src.parameters]
slope = 2.0
offset = [1.0, 2.0]
enabled = false
label = "hello"
[components.g]
fmu = "Gain"
parameters = { gain = 3 }
[record]
interval = 0.002
[[metrics]]
kind = "rmse"
name = "e"
estimate = "g.yv"
truth = "src.ys"
after = 0.01
"""


def test_load_resolves_components_parameters_connections(tmp_path, toy_dir):
    sc = load_scenario(write(tmp_path, BASE))
    assert (sc.name, sc.description, sc.stop_time, sc.base_step, sc.seed) == ("toy", "a toy", 0.1, 0.001, 7)
    assert sc.n_steps == 100 and sc.record_every == 2
    src, g = sc.components["src"], sc.components["g"]
    assert src.fmu == toy_dir / "Source.fmu" and src.ratio == 2 and g.ratio == 1
    assert src.parameters == {"slope": 2.0, "offset[1]": 1.0, "offset[2]": 2.0, "enabled": False,
                              "label": "hello", "seed": stable_seed(7, "src")}
    assert g.parameters == {"gain": 3.0} and isinstance(g.parameters["gain"], float)
    assert [str(c) for c in sc.connections] == ["src.y -> g.u", "src.ys -> g.uv"]
    assert sc.connections[1].pairs == (("ys[1]", "uv[1]"), ("ys[2]", "uv[2]"))
    # default record: every connected output, plus what the metrics need
    assert sc.record == ["src.y", "src.ys", "g.yv"]
    assert sc.record_columns() == ["src.y", "src.ys[1]", "src.ys[2]", "g.yv[1]", "g.yv[2]"]
    assert sc.metrics[0].after == 0.01


def test_seed_is_stable_per_component_and_given_seed_wins(tmp_path):
    assert stable_seed(7, "src") == stable_seed(7, "src")
    assert len({stable_seed(7, "src"), stable_seed(8, "src"), stable_seed(7, "other")}) == 3
    sc = load_scenario(write(tmp_path, BASE.replace("slope = 2.0", "slope = 2.0\nseed = 42")))
    assert sc.components["src"].parameters["seed"] == 42


def test_overrides(tmp_path):
    path = write(tmp_path, BASE)
    sc = load_scenario(path, ["src.slope=5", "src.offset=[3, 4]", "g.gain=0.5", "scenario.seed=3",
                              "scenario.stop_time=2", "src.label=world"])
    p = sc.components["src"].parameters
    assert (p["slope"], p["offset[1]"], p["offset[2]"], p["label"]) == (5.0, 3.0, 4.0, "world")
    assert p["seed"] == stable_seed(3, "src")
    assert sc.components["g"].parameters["gain"] == 0.5
    assert (sc.seed, sc.stop_time) == (3, 2.0)
    sc = load_scenario(path, ["src.offset[2]=9.5"])
    assert sc.components["src"].parameters["offset[2]"] == 9.5
    assert sc.components["src"].parameters["offset[1]"] == 1.0
    assert parse_override(" a.b[2] = [1, 2] ") == ("a", "b", 2, [1, 2])
    assert parse_value('"x"') == "x" and parse_value("true") is True


def test_structured_overrides_load_like_their_strings(tmp_path):
    path = write(tmp_path, BASE)
    texts = ["src.slope=0.30000000000000004", "src.offset[2]=9.5", "src.label=\"a b\"", "scenario.seed=3",
             "g.gain=[1.5, 2]"]
    mapping = {("src", "slope"): 0.1 + 0.2, ("src", "offset", 2): np.float64(9.5), ("src", "label"): "a b",
               ("scenario", "seed"): 3, ("g", "gain"): (1.5, 2)}
    assert override_strings(mapping) == tuple(texts)
    assert override_strings(texts) == tuple(texts)
    sc = load_scenario(path, {k: v for k, v in mapping.items() if k[1] != "gain"})
    assert sc.overrides == tuple(texts[:4])               # recorded as strings, as --set gives them
    assert sc.components["src"].parameters == load_scenario(path, texts[:4]).components["src"].parameters
    assert sc.components["src"].parameters["slope"] == 0.1 + 0.2 and sc.seed == 3
    with pytest.raises(ScenarioError, match=r"override key 'src.slope': expected \(component, parameter\)"):
        override_strings({"src.slope": 1.0})
    with pytest.raises(ScenarioError, match="not the string"):
        override_strings("src.slope=1")


@pytest.mark.parametrize("value", [0.1 + 0.2, -1e-300, float("inf"), 3, True, "x \"q\" \\ é",
                                   [1.5, [2, 3]], {"m": 2.0, "n": [1, 2]}])
def test_toml_value_reads_back_to_the_same_value(value):
    assert parse_value(toml_value(value)) == value


def test_include_merges_parameters(tmp_path):
    (tmp_path / "tuned").mkdir()
    write(tmp_path / "tuned", '[components.g.parameters]\ngain = 7.0\noffset = 1.5\n', "t.toml")
    text = BASE.replace('seed = 7', 'seed = 7\ninclude = ["tuned/t.toml"]')
    sc = load_scenario(write(tmp_path, text))
    assert sc.components["g"].parameters == {"gain": 7.0, "offset": 1.5}
    sc = load_scenario(tmp_path / "s.toml", ["g.gain=1"])       # an override wins over the include
    assert sc.components["g"].parameters["gain"] == 1.0
    write(tmp_path / "tuned", '[components.nope.parameters]\ngain = 7.0\n', "t.toml")
    with pytest.raises(ScenarioError, match=r"t\.toml: unknown component 'nope'"):
        load_scenario(tmp_path / "s.toml")


def test_merge_include_updates_parameters_and_sets_of_a_document(tmp_path):
    write(tmp_path, '[components.g.parameters]\ngain = 7.0\n[components.other.parameters]\nk = 1\n'
          '[parameter_sets.robot]\nm = 2.0\n', "inc.toml")
    doc = {"components": {"g": {"parameters": {"gain": 1.0, "bias": 0.5}}},
           "parameter_sets": {"robot": {"m": 1.0, "k": 3.0}}}
    with pytest.raises(ScenarioError, match=r"inc\.toml: unknown component 'other' \(not in s\.toml\)"):
        merge_include(doc, tmp_path / "inc.toml", "s.toml")
    merge_include(doc, tmp_path / "inc.toml", skip_unknown=True)
    assert doc == {"components": {"g": {"parameters": {"gain": 7.0, "bias": 0.5}}},
                   "parameter_sets": {"robot": {"m": 2.0, "k": 3.0}}}
    write(tmp_path, '[scenario]\nname = "x"\n', "bad.toml")
    with pytest.raises(ScenarioError, match="unknown key"):
        merge_include(doc, tmp_path / "bad.toml")


def test_fmu_given_as_path_relative_to_the_scenario(tmp_path, toy_dir):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "mine.fmu").write_bytes((toy_dir / "Gain.fmu").read_bytes())
    sc = load_scenario(write(tmp_path, BASE.replace('fmu = "Gain"', 'fmu = "sub/mine.fmu"')))
    assert sc.components["g"].fmu == tmp_path / "sub" / "mine.fmu"


@pytest.mark.parametrize("change, message", [
    (('"src.y -> g.u"', '"srx.y -> g.u"'), r"s\.toml: connection 'srx\.y -> g\.u': unknown component 'srx'"),
    (('"src.y -> g.u"', '"src.z -> g.u"'), r"connection 'src\.z -> g\.u': component 'src' \(Source\) has no variable 'z'"),
    (('"src.y -> g.u"', '"src.y -> g.y"'), r"output-to-output connection: the target 'g\.y' is an output"),
    (('"src.y -> g.u"', '"g.u -> g.u"'), r"input-to-input connection: the source 'g\.u' is an input"),
    (('"src.y -> g.u"', '"src.y -> g.gain"'), r"connection 'src\.y -> g\.gain': the target 'g\.gain' is a parameter, must be an input"),
    (('"src.ys -> g.uv"', '"src.ys -> g.u"'), r"size mismatch: 'src\.ys' has 2 element\(s\), 'g\.u' has 1"),
    (('"src.y -> g.u"', '"src.t_s -> g.u"'), r"connection 'src\.t_s -> g\.u': unit mismatch: 'src\.t_s' is in s, 'g\.u' in 1"),
    (('fmu = "Gain"', 'fmu = "Nope"'), r"component 'g': FMU file not found: .*Nope\.fmu"),
    (('fmu = "Gain"', 'fmu = "x/missing.fmu"'), r"component 'g': FMU file not found: .*x/missing\.fmu"),
    (("step = 0.002", "step = 0.0025"), r"component 'src': step = 0\.0025 is not an integer multiple of the base step 0\.001"),
    (('"src.ys -> g.uv"]', '"src.ys -> g.uv", "src.n -> g.u"]'), r"input 'g\.u' is already connected by 'src\.y -> g\.u'"),
    (("slope = 2.0", "slop = 2.0"), r"component 'src': component 'src' has no parameter 'slop'"),
    (("slope = 2.0", "slope = [2.0]"), r"parameter 'slope' is a scalar"),
    (("offset = [1.0, 2.0]", "offset = [1.0]"), r"parameter 'offset' has 2 elements, got 1"),
    (("slope = 2.0", 'slope = "fast"'), r"parameter 'slope' is Real, got 'fast'"),
    (("interval = 0.002", "interval = 0.0015"), r"\[record\] interval = 0\.0015 is not an integer multiple"),
    (('estimate = "g.yv"', 'estimate = "g.y"'), r"metric 'e': size mismatch"),
    (('kind = "rmse"', 'kind = "median"'), r"unknown kind 'median'"),
    (('kind = "rmse"', 'kind = "nees"'), r"'covariance' is missing \(kind 'nees'\)"),
    (('kind = "rmse"', 'kind = "nis"'), r"'dof' is missing \(kind 'nis'\)"),
    (('kind = "rmse"', 'kind = "nees"\ncovariance = "src.ys"'),
     r"metric 'e': covariance 'src.ys' has 2 elements: not a packed covariance"),
    (('kind = "rmse"', 'kind = "nees"\ncovariance = "src.ys"\ndof = 3'),
     r"the NEES of 2 states has 2 degrees of freedom, got dof = 3"),
    (('kind = "rmse"', 'kind = "nis"\ndof = 1'), r"estimate 'g.yv' must be a scalar"),
    (("stop_time = 0.1", "stop_time = -1"), r"stop_time must be > 0"),
    (("[record]", "[recrod]"), r"s\.toml: unknown key\(s\) recrod"),
])
def test_validation_errors_name_file_component_variable(tmp_path, change, message):
    old, new = change
    assert old in BASE
    path = write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(ScenarioError, match=message) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_malformed_toml_names_file_and_line(tmp_path):
    path = write(tmp_path, BASE.replace("slope = 2.0", "slope = = 2.0"))
    with pytest.raises(ScenarioError, match=r"s\.toml: malformed TOML: .*line 13, column 9"):
        load_scenario(path)


def test_missing_scenario_file(tmp_path):
    with pytest.raises(ScenarioError, match=r"scenario file not found: .*nope\.toml"):
        load_scenario(tmp_path / "nope.toml")


@pytest.mark.parametrize("override, message", [
    ("nope.x=1", r"unknown component 'nope'"),
    ("src.nope=1", r"has no parameter 'nope'"),
    ("scenario.colour=1", r"unknown scenario key 'colour'"),
    ("src.slope", r"expected comp\.param=value"),
    ("src.slope=[1,", r"not a TOML value"),
    ("scenario.base_step=0.0008", r"component 'src': step = 0\.002 is not an integer multiple of the base step 0\.0008"),
])
def test_bad_overrides(tmp_path, override, message):
    with pytest.raises(ScenarioError, match=message):
        load_scenario(write(tmp_path, BASE), [override])


def test_copy_document_shares_no_table_or_array():
    doc = {"components": {"g": {"parameters": {"v": [1.0, [2.0]]}}}, "connections": ["a.x -> b.y"]}
    copy = copy_document(doc)
    assert copy == doc
    copy["components"]["g"]["parameters"]["v"][1].append(3.0)
    copy["connections"].clear()
    assert doc == {"components": {"g": {"parameters": {"v": [1.0, [2.0]]}}}, "connections": ["a.x -> b.y"]}


def test_model_descriptions_are_parsed_once_per_fmu_content(tmp_path, toy_dir, monkeypatch):
    """The variables of an FMU come back from the disk cache in a new process (here: the
    in-memory one emptied) without parsing, as parsed; a changed FMU is parsed anew."""
    import shutil
    import zipfile

    from orchestration import scenario
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(scenario, "_MD_CACHE", {})
    parsed = []
    parse = scenario._parse_variables
    monkeypatch.setattr(scenario, "_parse_variables", lambda fmu: parsed.append(fmu.name) or parse(fmu))
    gain = tmp_path / "Gain.fmu"
    shutil.copy(toy_dir / "Gain.fmu", gain)
    first = scenario.read_variables(gain)
    monkeypatch.setattr(scenario, "_MD_CACHE", {})
    again = scenario.read_variables(toy_dir / "Gain.fmu")          # the same content elsewhere
    assert parsed == ["Gain.fmu"] and again == first
    assert first[0] == "Gain" and first[2]["y"].depends_on == ("u",) and first[2]["u"].depends_on is None
    assert len(list((tmp_path / "cache" / "model_descriptions").glob("*.json"))) == 1
    with zipfile.ZipFile(gain, "a") as z:
        z.writestr("documentation/notes.txt", "changed")
    assert scenario.read_variables(gain) == first and parsed == ["Gain.fmu", "Gain.fmu"]
