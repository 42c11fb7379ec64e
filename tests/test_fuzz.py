"""Fuzzing the readers of user files (issue 27): any input ends in success or in the one
exception the command line turns into one ``error:`` line, never in another exception.

Property-based (Hypothesis) over the four readers a user hands files to:

===================  =========================================  ================================
reader               inputs                                     allowed failure
===================  =========================================  ================================
state file           bytes; JSON values; a valid state's        ``ScenarioError``
(``fork``)           entries replaced, deleted or added
LogReplay log        CSV text and bytes; HDF5 datasets of any   ``ParameterError`` (the FMU's
(``log_replay``)     type and shape; column maps; parameters    error, the master's one line)
scenario file        a toy scenario's TOML edited as text;      ``ScenarioError``
(``scenario``)       its entries replaced, deleted or added
SSP package          bytes; a hand-written SSD edited as text   ``ScenarioError``
(``ssp``)            or XML
===================  =========================================  ================================

The CLI prints the exception's message as its one line (``cli._error`` joins its lines: a
column name in quotes may hold a line break). Each property runs in two profiles: ``fast`` in ``make test`` (derandomised, so the same
examples each time: a few seconds in all) and ``long``, marked ``slow`` (``make test-slow``),
with many more, random examples. A failure prints the smallest input Hypothesis found.
"""
from __future__ import annotations

import base64
import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmus.common.parameters import ParameterError, validate
from fmus.robot_plant.log_replay_fmu import SIGNALS
from fmus.robot_plant.log_replay_model import LogReplayParameters, RecordedLog
from orchestration import fork
from orchestration.scenario import ScenarioError

#: examples per property: fast (make test) and long (make test-slow)
PROFILES = [pytest.param(dict(max_examples=30, derandomize=True), id="fast"),
            pytest.param(dict(max_examples=1500), id="long", marks=pytest.mark.slow)]


def fuzz(profile: dict, *strategies: Any) -> Any:
    """``@given(*strategies)`` with the profile's settings (no example database in the
    repository, no deadline: the machine is shared)."""
    def wrap(check: Any) -> Any:
        return settings(deadline=None, database=None, **profile,
                        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                               HealthCheck.filter_too_much])(given(*strategies)(check))
    return wrap


# ---- values ---------------------------------------------------------------------------------
SCALARS = st.one_of(st.none(), st.booleans(), st.integers(min_value=-2 ** 70, max_value=2 ** 70),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                    st.sampled_from([0, 1, -1, 0.5, 1e18, -1e18, 1e-12, 1e308, "0.5", "", "AAAA"]))
JSON = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                     st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                    max_leaves=12)


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (keys and indices) into a JSON-like document."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, prefix + (i,))
    return out


def mutated(doc: Any, data: st.DataObject, values: st.SearchStrategy, times: int = 3) -> Any:
    """``doc`` (a copy) with up to ``times`` entries replaced by a drawn value, deleted, or a key
    added."""
    doc = json.loads(json.dumps(doc))
    for _ in range(data.draw(st.integers(1, times))):
        paths = _paths(doc)
        path = data.draw(st.sampled_from(paths))
        if not path:
            continue
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        action = data.draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = data.draw(values)
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[data.draw(st.text(max_size=8))] = data.draw(values)
    return doc


def text_mutated(text: str, data: st.DataObject, alphabet: str) -> str:
    """``text`` with up to three spans replaced by drawn text of ``alphabet`` (edits a file as a
    careless hand would: a cut, a paste, a typo)."""
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(text)))
        j = data.draw(st.integers(i, min(len(text), i + 40)))
        text = text[:i] + data.draw(st.text(alphabet, max_size=12)) + text[j:]
    return text


@st.composite
def edits(draw: Any, text: str, alphabet: str) -> str:
    """:func:`text_mutated` as a strategy."""
    class Drawer:
        def draw(self, strategy: st.SearchStrategy) -> Any:
            return draw(strategy)
    return text_mutated(text, Drawer(), alphabet)      # type: ignore[arg-type]


# ---- the state file -------------------------------------------------------------------------
STATE = {"format": fork.FORMAT, "time": 0.5, "step": 500, "scenario": "chain",
         "structure": {"base_step": 0.001,
                       "components": {"src": {"model_identifier": "Source", "guid": "{g}", "step": 0.001,
                                              "parameters": {"slope": 3.0}},
                                      "g": {"model_identifier": "Gain", "guid": "{h}", "step": 0.002,
                                            "parameters": {}}},
                       "connections": ["src.y -> g.u"]},
         "values": {"src.y": 1.5, "g.y": 3.0},
         "fmus": {"src": base64.b64encode(b"state of src").decode(), "g": base64.b64encode(b"g").decode()}}


def _read_state(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "state.json"
    path.write_bytes(content)
    try:
        doc = fork.read_state(path)
    except ScenarioError as exc:
        assert str(exc).strip()
        return
    # accepted: what the run then relies on holds
    assert isinstance(doc["step"], int) and doc["step"] > 0 and math.isfinite(doc["time"])
    assert all(isinstance(b, bytes) for b in doc["fmus"].values())


@pytest.mark.parametrize("profile", PROFILES)
def test_the_state_reader_takes_any_bytes(profile: dict, tmp_path: Path) -> None:
    @fuzz(profile, st.one_of(st.binary(max_size=200), JSON.map(lambda v: json.dumps(v).encode())))
    def check(content: bytes) -> None:
        _read_state(tmp_path, content)
    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_the_state_reader_takes_any_edit_of_a_state(profile: dict, tmp_path: Path) -> None:
    @fuzz(profile, st.data())
    def check(data: st.DataObject) -> None:
        _read_state(tmp_path, json.dumps(mutated(STATE, data, JSON)).encode())
    check()


# ---- the LogReplay log ----------------------------------------------------------------------
OUTPUTS = {s.name: (s.size, s.unit) for s in SIGNALS}
LOG_TEXT = "time,a,b,stamp\n0.0,0.0,10.0,0.0\n0.01,1.0,20.0,0.01\n0.02,2.0,30.0,0.02\n"
COLUMN_MAPS = st.one_of(
    st.sampled_from(["q_m_meas[1] = a; q_m_meas[2] = b", "phi_fk = a", "q_m_meas = a",
                     "phi_fk = a [deg]; t_meas = stamp", "phi_fk = a [furlong]", "phi_fk = nope",
                     "acc_s[4] = a", "phi_fk = a; phi_fk = b", "=", ";;", "phi_fk", ""]),
    st.text("abtime_[]=; mqsdeg0123\n", max_size=30))
LOG_PARAMETERS = st.fixed_dictionaries({
    "columns": COLUMN_MAPS,
    "time_column": st.sampled_from(["time", "a", "nope", ""]),
    "interpolation": st.sampled_from(["hold", "linear", "cubic"]),
    "time_offset": st.one_of(st.sampled_from([0.0, 0.01, -1.0]), st.floats()),
    "max_gap": st.one_of(st.sampled_from([0.05, 1.0]), st.floats()),
})


def _replay(path: Path, params: dict, times: list[float]) -> None:
    """Build the log as the FMU does (the parameters validated first), then sample it."""
    try:
        p = validate(LogReplayParameters(log_file=str(path), **params))
        log = RecordedLog(p, OUTPUTS, stamp="t_meas")
        for t in times:
            values, taken = log.sample(t)
            assert values.shape == (len(log.mappings),) and isinstance(taken, float)
    except ParameterError as exc:
        assert str(exc).strip()      # (the CLI's error line joins what a quoted name spreads over lines)


@pytest.mark.parametrize("profile", PROFILES)
def test_the_log_reader_takes_any_csv(profile: dict, tmp_path: Path) -> None:
    texts = st.one_of(edits(LOG_TEXT, "0123456789.,-e\n\"\r ;nan\x00abtime"), st.text(max_size=120))
    @fuzz(profile, st.one_of(texts.map(str.encode), st.binary(max_size=200)), LOG_PARAMETERS,
          st.lists(st.floats(-1.0, 1.0), max_size=3))
    def check(content: bytes, params: dict, times: list[float]) -> None:
        path = tmp_path / "log.csv"
        path.write_bytes(content)
        _replay(path, params, times)
    check()


DTYPES = ["f8", "f4", "i4", "u1", "?", "c16", "S3", "O", [("x", "f8"), ("y", "i4")]]


@pytest.mark.parametrize("profile", PROFILES)
def test_the_log_reader_takes_any_hdf5(profile: dict, tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    dataset = st.tuples(st.sampled_from(range(len(DTYPES))), st.sampled_from([(0,), (1,), (3,), (3, 2), ()]),
                        st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=6))

    @fuzz(profile, st.dictionaries(st.sampled_from(["time", "a", "b", "stamp", "g/a"]), dataset, max_size=4),
          LOG_PARAMETERS, st.lists(st.floats(-1.0, 1.0), max_size=3), st.booleans())
    def check(datasets: dict, params: dict, times: list[float], binary: bool) -> None:
        path = tmp_path / "log.h5"
        if binary:
            path.write_bytes(json.dumps(datasets).encode())
        else:
            with h5py.File(path, "w") as f:
                for name, (kind, shape, numbers) in datasets.items():
                    dtype = np.dtype(DTYPES[kind]) if DTYPES[kind] != "O" else h5py.string_dtype()
                    n = int(np.prod(shape))
                    raw = np.resize(np.cumsum(np.abs(numbers)), n).reshape(shape)
                    if dtype.names:
                        data = np.zeros(shape, dtype=dtype)
                    elif dtype.kind == "S":
                        data = np.array([str(x)[:3].encode() for x in raw.ravel()], dtype=dtype).reshape(shape)
                    elif dtype.kind == "O":
                        data = np.array([str(x)[:3] for x in raw.ravel()], dtype=object).reshape(shape)
                    else:
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            data = raw.astype(dtype)
                    f.create_dataset(name, data=data, dtype=dtype)
        _replay(path, params, times)
    check()


# ---- the scenario file and the SSP package (toy FMUs) ---------------------------------------
@pytest.fixture
def handmade_files(tmp_path: Path, toy_dir: Path, toy_fmus: None) -> Path:
    """A folder with the hand-written SSD's FMUs and SSVs (tests/test_ssp.py) in resources/."""
    from test_ssp import ROOT_SSV, SOURCE_SSV
    (tmp_path / "resources").mkdir()
    for fmu in ("Source", "Gain", "MassSpring"):
        (tmp_path / "resources" / f"{fmu}.fmu").write_bytes((toy_dir / f"{fmu}.fmu").read_bytes())
    (tmp_path / "resources" / "source.ssv").write_text(SOURCE_SSV)
    (tmp_path / "resources" / "root.ssv").write_text(ROOT_SSV)
    return tmp_path


def _load(path: Path, overrides: tuple[str, ...] = ()) -> None:
    from orchestration.cli import loaded
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")          # a warning is a line, not a failure
            with loaded(path, overrides) as sc:
                assert sc.n_steps >= 1 and sc.components
    except ScenarioError as exc:
        assert str(exc).strip()


TOML_ALPHABET = "abcxyz_.=[]{}\"'#, \n0123456789-+e\\"


@pytest.mark.parametrize("profile", PROFILES)
def test_the_scenario_loader_takes_any_edit_of_a_scenario_file(profile: dict, handmade_files: Path) -> None:
    from test_ssp import HANDMADE_TOML

    @fuzz(profile, st.data())
    def check(data: st.DataObject) -> None:
        path = handmade_files / "handmade.toml"
        path.write_text(text_mutated(HANDMADE_TOML, data, TOML_ALPHABET))
        _load(path)
    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_the_scenario_loader_takes_any_value_anywhere(profile: dict, handmade_files: Path) -> None:
    import tomllib

    from test_ssp import HANDMADE_TOML
    from toys import toml_document
    toml_values = st.recursive(
        st.one_of(st.booleans(), st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(), st.text(max_size=10),
                  st.sampled_from(["Gain", "src.y -> gain.u", "gain.y", 0.002, 1e-12, 1e9, -1, 0])),
        lambda inner: st.one_of(st.lists(inner, max_size=3),
                                st.dictionaries(st.text("abcgkmnoprstuy_", max_size=8), inner, max_size=3)),
        max_leaves=6)
    overrides = st.lists(st.text("abcgainsourcestop_time.=[]0123456789e-", max_size=20), max_size=2)

    @fuzz(profile, st.data(), overrides)
    def check(data: st.DataObject, extra: list[str]) -> None:
        path = handmade_files / "handmade.toml"
        doc = mutated(tomllib.loads(HANDMADE_TOML), data, toml_values)
        path.write_text(toml_document(doc) if isinstance(doc, dict) else "")
        _load(path, tuple(extra))
    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_the_ssp_reader_takes_any_edit_of_an_ssd(profile: dict, handmade_files: Path) -> None:
    from test_ssp import HANDMADE

    @fuzz(profile, st.data())
    def check(data: st.DataObject) -> None:
        path = handmade_files / "SystemStructure.ssd"
        path.write_text(text_mutated(HANDMADE, data, "<>/=\"' abcdefgimnoprstuvxyz:.0123456789[]-\n"))
        _load(path)
    check()


@pytest.mark.parametrize("profile", PROFILES)
def test_the_ssp_reader_takes_any_package(profile: dict, tmp_path: Path) -> None:
    import io
    import zipfile

    @fuzz(profile, st.one_of(st.binary(max_size=300),
                             st.dictionaries(st.sampled_from(["SystemStructure.ssd", "resources/a.fmu",
                                                              "../x", "/abs", "resources/", "c:/x"]),
                                             st.binary(max_size=60), max_size=3)))
    def check(content: Any) -> None:
        path = tmp_path / "x.ssp"
        if isinstance(content, dict):
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w") as z:
                for name, data in content.items():
                    z.writestr(name, data)
            content = buffer.getvalue()
        path.write_bytes(content)
        _load(path)
    check()
