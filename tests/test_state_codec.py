"""The data-only FMU state format (fmus/common/state_codec.py): everything an FMU's state holds
comes back bit for bit, and no byte string runs code or crashes the reader."""
from __future__ import annotations

import json
import math
import os
import pickle
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from fmus.common import state_codec
from fmus.common.fmi import FlexFusionSlave
from fmus.common.frames import RigidMount
from fmus.common.state_codec import MAGIC, StateError, decode, encode

IDENTITY = {"model": "Toy", "build": "0" * 32}


@dataclass(frozen=True)
class Point:
    x: float
    y: float


class Pair(NamedTuple):
    a: object
    b: object


class Node:
    def __init__(self, value: object) -> None:
        self.value = value
        self.next: Node | None = None


class Live:
    def __init__(self, name: str) -> None:
        self.name = name


def round_trip(obj: object, **kwargs: object) -> object:
    data = encode(obj, IDENTITY, script=__name__, bound=Live, **kwargs)
    return decode(data, IDENTITY, script=__name__, bound=lambda name: ("live", name))


def test_every_node_type_comes_back_bit_for_bit_with_its_sharing() -> None:
    shared = np.arange(6.0).reshape(2, 3)
    fortran = np.asfortranarray(np.arange(12.0).reshape(3, 4))
    rng = np.random.default_rng(5)
    rng.normal(size=3)
    cycle = Node(1)
    cycle.next = cycle
    obj = {"floats": [0.1, -0.0, math.nan, math.inf, 5e-324], "ints": (0, -3, 2 ** 80), "flags": [True, False],
           "none": None, "text": "é\0", "scalar": np.float64(1.5), "int32": np.int32(-7),
           "arrays": [shared, shared, fortran, np.zeros((0, 3)), np.array([1 + 2j]), np.array([True])],
           "point": Point(1.0, 2.0), "pair": Pair(shared, Point(3.0, 4.0)), "cycle": cycle, "rng": rng,
           1.5: "float key", (1, "a"): "tuple key", "live": Live("q_a"), "mount": RigidMount.__new__(RigidMount)}
    vars(obj["mount"]).update(r=np.ones(3))
    back = round_trip(obj)
    assert back.keys() == obj.keys()
    for a, b in zip(back["floats"], obj["floats"]):
        assert a.hex() == b.hex()
    assert back["ints"] == obj["ints"] and back["flags"] == obj["flags"] and back["none"] is None
    assert back["text"] == obj["text"] and back["scalar"] == 1.5 and type(back["int32"]) is np.int32
    arrays = back["arrays"]
    assert arrays[0] is arrays[1] and arrays[0] is back["pair"].a            # shared stays shared
    assert_array_equal(arrays[0], shared) and arrays[0].flags.writeable
    assert arrays[2].flags.f_contiguous and not arrays[2].flags.c_contiguous
    assert_array_equal(arrays[2], fortran)
    assert arrays[3].shape == (0, 3) and arrays[4].dtype == complex and arrays[5].dtype == bool
    assert back["point"] == Point(1.0, 2.0) and type(back["pair"]) is Pair
    assert back["cycle"].next is back["cycle"]
    assert_array_equal(back["rng"].normal(size=4), rng.normal(size=4))     # the generator continues
    assert back[1.5] == "float key" and back[(1, "a")] == "tuple key"
    assert back["live"] == ("live", "q_a")
    assert type(back["mount"]) is RigidMount
    assert_array_equal(back["mount"].r, np.ones(3))


@pytest.mark.parametrize("value", [lambda: 0, {1, 2}, np.array([object()]), os, print, Path("x"),
                                   np.random.RandomState(1)])
def test_what_is_not_data_is_refused_when_encoding(value: object) -> None:
    with pytest.raises(TypeError, match="not part of the state format"):
        encode({"v": value}, IDENTITY)


class Payload:
    """Unpickling it would create the marker file (what a crafted state.json did)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_pickle_with_a_payload_is_refused_and_does_not_run(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    data = pickle.dumps({"arrays": {}, "attrs": Payload(marker)})
    pickle.loads(pickle.dumps(Payload(tmp_path / "control")))
    assert (tmp_path / "control").exists()                          # the payload works when unpickled
    with pytest.raises(StateError, match="a pickle .* data only"):
        decode(data, IDENTITY, bound=lambda name: name)
    assert not marker.exists()


def craft(head: dict | str, blob: bytes = b"") -> bytes:
    """A state with valid lengths and CRC around any header: what an attacker can write."""
    header = (head if isinstance(head, str) else json.dumps(head)).encode()
    return struct.pack("<16sIQQ", MAGIC, zlib.crc32(header + blob), len(header), len(blob)) + header + blob


def refused(data: bytes, match: str) -> None:
    with pytest.raises(StateError, match=match):
        decode(data, IDENTITY, script=__name__, bound=lambda name: name, forbidden=(FlexFusionSlave,))


def test_a_truncated_or_corrupted_state_is_refused() -> None:
    data = encode({"x": np.arange(100.0), "s": "text"}, IDENTITY)
    refused(data + b"\0", "truncated or padded")
    for n in (0, 10, len(MAGIC) + 20, len(MAGIC) + 40, len(data) // 2, len(data) - 1):
        with pytest.raises(StateError, match="truncated|corrupted"):
            decode(data[:n], IDENTITY, bound=lambda name: name)
    for i in (len(MAGIC) + 1, len(MAGIC) + 50, len(data) - 3):              # the CRC, the header, an array
        bad = bytearray(data)
        bad[i] ^= 0x01
        with pytest.raises(StateError, match="corrupted"):
            decode(bytes(bad), IDENTITY, bound=lambda name: name)
    refused(b"{\"format\": \"flexfusion-state-1\"}" + bytes(64), "not a FlexFusion state")


def test_the_state_of_another_fmu_or_build_is_refused() -> None:
    data = encode({"x": 1.0}, {"model": "Encoder", "build": "1" * 32})
    with pytest.raises(StateError, match="another FMU or build .*build.*model"):
        decode(data, IDENTITY, bound=lambda name: name)
    refused(craft({"format": 2, "identity": IDENTITY, "tree": ["n"], "arrays": []}), "format 2")


@pytest.mark.parametrize("tree, arrays, match", [
    (["o", "~.os:system", 0, []], [], "not one of this FMU's"),                     # a module not ours
    (["o", "os:system", 0, []], [], "not one of this FMU's"),
    (["o", "@:os", 0, []], [], "not one of this FMU's"),                            # imported, not defined, here
    (["o", "@:Path", 0, []], [], "not one of this FMU's"),
    (["o", "~.common.state_codec:StateError", 0, []], [], "not a plain object"),     # an exception class
    (["o", "~.common.fmi:FlexFusionSlave", 0, []], [], "not a plain object"),        # forbidden: an FMU
    (["T", "@:Point", [["f", "0x1p+0"]]], [], "not a named tuple"),
    (["o", "@:Payload", 0, [["marker", ["s", "/tmp/x"]]]], [], None),                # ours: made, not called
    (["a", 0, 0], [["|O", [1], "C", 0, 8]], "only numbers"),
    (["a", 0, 0], [["<f8", [10], "C", 0, 80]], "do not hold"),                      # past the blob's end
    (["a", 0, 0], [["<f8", [2 ** 40, 2 ** 40], "C", 0, 16]], "do not hold"),
    (["a", 0, 0], [["<f8", [-1], "C", 0, 8]], "malformed array"),
    (["g", 0, ["d", 1, [[["s", "bit_generator"], ["s", "Evil"]]]]], [], "only PCG64"),
    (["r", 7], [], "reference to node 7"),
    (["l", 0, [["r", 0], ["l", 0, []]]], [], "reused"),
    (["q"], [], "unknown or malformed"),
    ("not a node", [], "malformed node"),
    (["f", 1.0], [], "unknown or malformed"),
    (["d", 0, [[["l", 1, []], ["n"]]]], [], "dict key of type list"),
    (["x", "<f8", "00"], [], "numpy scalar"),
    (["i", "1" * 10], [], "unknown or malformed"),
])
def test_a_crafted_state_with_a_valid_digest_makes_nothing_but_data(tree, arrays, match) -> None:
    data = craft({"format": 1, "identity": IDENTITY, "tree": tree, "arrays": arrays}, bytes(8))
    if match is None:
        made = decode(data, IDENTITY, script=__name__, bound=lambda name: name)
        assert type(made) is Payload and made.marker == "/tmp/x"    # no __init__, no __reduce__
        return
    refused(data, match)


def test_deep_nesting_is_refused_not_a_crash() -> None:
    tree: list = ["n"]
    for _ in range(state_codec.MAX_DEPTH + 5):
        tree = ["t", [tree]]
    refused(craft({"format": 1, "identity": IDENTITY, "tree": tree, "arrays": []}), "nested deeper")
    deep = "[" * 100000 + "]" * 100000                 # the JSON parser's own limit
    refused(craft('{"format": 1, "identity": %s, "tree": %s, "arrays": []}' % (json.dumps(IDENTITY), deep)),
            "unreadable header|nested")
