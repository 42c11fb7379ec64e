"""A data-only serialisation of an FMU's internal state (no pickle, nothing is called).

An FMU state travels: ``fmi2SerializeFMUstate`` hands it to a host, a state file
(``flexfusion run --from-state``) carries it between users and machines. Whoever crafts the
bytes must not be able to run code in the FMU that reads them, so the bytes hold only data:

``MAGIC`` (16 bytes) | CRC-32 of the rest (4 bytes) | header length (8 bytes) | length of the
arrays' bytes (8 bytes) | header (JSON, UTF-8) | the arrays' bytes, one after the other
(integers little endian). The lengths and the CRC find a truncated or damaged state; the CRC
is no signature (anyone can compute it): whatever the bytes say, they are read as data only.

The header holds the format ``VERSION``, the ``identity`` the caller gives (for an FMU: its
model identifier and a hash of its build and variables), the object ``tree`` and, for each
array, its dtype (booleans, integers, floats and complex numbers only), shape, order and
where its bytes lie. The tree is made of JSON lists ``[tag, ...]``:

====  ==========================================================================
tag   node
====  ==========================================================================
n     None
b     bool
i     int
f     float (``float.hex``: every bit, also NaN and infinities)
s     str
x     numpy scalar (dtype, hex of its bytes)
a     numpy array (index into the header's ``arrays``; an id: shared arrays stay shared)
l, d  list, dict (a list of ``[key, value]`` pairs: keys need not be strings); ids
t     tuple; ``T``: a named tuple of an allowed class
o     an object of an allowed class (its ``__dict__``), with an id
g     a ``numpy.random.Generator`` over one of :data:`BIT_GENERATORS` (its state)
B     the name of a live object (:func:`encode`'s ``bound``, given back by :func:`decode`)
r     a reference to an earlier node with an id (shared objects, cycles)
====  ==========================================================================

Allowed classes are those of the package this module is in (``fmus`` or an FMU's
``fmus_<hash>``) and of one more module the caller names (an FMU's own script), looked up
among the modules already imported (nothing is imported), by module and qualified name,
checked to be defined there. An object is made with ``object.__new__`` and its ``__dict__``
filled (a named tuple with ``tuple.__new__``): no constructor, ``__setstate__``,
``__reduce__`` or ``__setattr__`` of the class runs. Anything else, a bad CRC, a truncated
blob, another identity or an unknown tag is a :class:`StateError` naming why.
"""
from __future__ import annotations

import functools
import json
import re
import struct
import sys
import zlib
from typing import Any, Callable

import numpy as np

MAGIC = b"FlexFusionState\0"          #: the first bytes of a serialised state
VERSION = 1                           #: the format's version (the header's ``format``)
BIT_GENERATORS = ("PCG64", "PCG64DXSM", "Philox", "SFC64", "MT19937")   #: restorable generators
MAX_DEPTH = 200                       #: nesting of the tree (a deeper one is refused)
_PACKAGE = __name__.partition(".")[0]  # ``fmus`` or ``fmus_<hash>``
_DTYPE = re.compile(r"[<>|=]?[biufc][0-9]{1,2}")   # bool, int, uint, float, complex only
_PREFIX = struct.Struct("<16sIQQ")


class StateError(ValueError):
    """A serialised state that cannot be read (the message says why)."""


def _module_key(module: str, script: str | None) -> str:
    """The name of the module ``module`` in a state: ``~<path in the package>`` or ``@`` for
    the caller's ``script`` module."""
    if module == script:
        return "@"
    if module == _PACKAGE or module.startswith(_PACKAGE + "."):
        return "~" + module[len(_PACKAGE):]
    raise TypeError(f"a {module} object is not part of the state format")


@functools.lru_cache(maxsize=1024)
def _plain(cls: type, forbidden: tuple[type, ...]) -> bool:
    """Whether objects of ``cls`` are plain data: a ``__dict__`` and nothing else (no slots,
    no ``__new__`` or ``__del__`` of their own, not a container, class or exception), and not
    one of the ``forbidden`` classes (an FMU itself)."""
    return (not issubclass(cls, (tuple, list, dict, set, frozenset, type, BaseException, *forbidden))
            and cls.__dictoffset__ != 0 and cls.__new__ is object.__new__ and not hasattr(cls, "__del__")
            and not any(vars(b).get("__slots__") for b in cls.__mro__))


def encode(obj: Any, identity: dict[str, Any], *, bound: type | None = None,
           script: str | None = None, forbidden: tuple[type, ...] = ()) -> bytes:
    """The bytes of ``obj`` (a tree of the node types in the module docstring) stamped with
    ``identity`` (JSON-able). An object of the class ``bound`` stands for a live object: only
    its ``name`` is stored; ``script`` is one more module whose classes are allowed (besides
    the package's); objects of the ``forbidden`` classes are refused. A value of another type
    raises ``TypeError``."""
    ids: dict[int, int] = {}
    keep: list[Any] = []                  # ids stay unique while encoding
    arrays: list[list[Any]] = []
    chunks: list[bytes] = []
    offset = 0

    def cls_name(t: type) -> str:
        if "<locals>" in t.__qualname__:
            raise TypeError(f"a local class {t.__qualname__} is not part of the state format")
        return f"{_module_key(t.__module__, script)}:{t.__qualname__}"

    def new_id(x: Any) -> int:
        ids[id(x)] = n = len(ids)
        keep.append(x)
        return n

    def node(x: Any) -> Any:
        nonlocal offset
        if x is None:
            return ["n"]
        t = type(x)
        if t is bound:
            return ["B", str(x.name)]
        if t is bool:
            return ["b", x]
        if t is int:
            return ["i", x]
        if t is float:
            return ["f", x.hex()]
        if t is str:
            return ["s", x]
        if id(x) in ids:
            return ["r", ids[id(x)]]
        if t is np.ndarray:
            if not _DTYPE.fullmatch(x.dtype.str):
                raise TypeError(f"an array of dtype {x.dtype} is not part of the state format")
            order = "F" if x.flags.f_contiguous and not x.flags.c_contiguous else "C"
            data = x.T if order == "F" else np.ascontiguousarray(x)   # C order: the same bytes, no copy
            arrays.append([x.dtype.str, list(x.shape), order, offset, data.nbytes])
            chunks.append(memoryview(data.reshape(-1)).cast("B") if data.size else b"")
            offset += data.nbytes
            return ["a", len(arrays) - 1, new_id(x)]
        if isinstance(x, np.generic):
            if not _DTYPE.fullmatch(x.dtype.str):
                raise TypeError(f"a numpy scalar of dtype {x.dtype} is not part of the state format")
            return ["x", x.dtype.str, x.tobytes().hex()]
        if t is tuple:
            return ["t", [node(v) for v in x]]
        if t is list:
            n = new_id(x)
            return ["l", n, [node(v) for v in x]]
        if t is dict:
            n = new_id(x)
            return ["d", n, [[node(k), node(v)] for k, v in x.items()]]
        if t is np.random.Generator:
            name = type(x.bit_generator).__name__
            if name not in BIT_GENERATORS:
                raise TypeError(f"a generator over {name} is not part of the state format")
            return ["g", new_id(x), node(x.bit_generator.state)]
        if isinstance(x, tuple) and hasattr(t, "_fields"):
            return ["T", cls_name(t), [node(v) for v in x]]
        if not _plain(t, forbidden):
            raise TypeError(f"a {t.__module__}.{t.__qualname__} is not part of the state format")
        name = cls_name(t)
        n = new_id(x)
        return ["o", name, n, [[k, node(v)] for k, v in vars(x).items()]]

    header = json.dumps({"format": VERSION, "identity": identity, "tree": node(obj), "arrays": arrays},
                        separators=(",", ":"), allow_nan=False).encode()
    body = b"".join([header, *chunks])
    return _PREFIX.pack(MAGIC, zlib.crc32(body), len(header), offset) + body


def decode(data: bytes, identity: dict[str, Any], *, bound: Callable[[str], Any],
           script: str | None = None, forbidden: tuple[type, ...] = ()) -> Any:
    """The object :func:`encode` made the bytes ``data`` of, if they carry ``identity``;
    ``bound(name)`` gives what a bound name stands for (``KeyError``: none); ``script`` and
    ``forbidden`` as for :func:`encode`. Anything else raises :class:`StateError` naming why."""
    view = memoryview(data)
    if len(view) < _PREFIX.size:
        raise StateError(f"truncated: {len(view)} bytes, not even the {_PREFIX.size}-byte prefix")
    magic, crc, n_header, n_arrays = _PREFIX.unpack_from(view)
    if magic != MAGIC:
        what = "a pickle" if view[:1] == b"\x80" else "not a FlexFusion state"
        raise StateError(f"{what} (it does not start with {MAGIC!r}): a state is data only, and "
                         "nothing else is read")
    body = view[_PREFIX.size:]
    if len(body) != n_header + n_arrays:
        raise StateError(f"truncated or padded: {len(body)} bytes follow its prefix, it says "
                         f"{n_header} + {n_arrays}")
    if zlib.crc32(body) != crc:
        raise StateError("corrupted: its CRC-32 does not match its content")
    try:
        head = json.loads(bytes(body[:n_header]))
    except (ValueError, RecursionError) as exc:
        raise StateError(f"unreadable header: {exc}") from None
    if not isinstance(head, dict) or head.get("format") != VERSION:
        raise StateError(f"format {head.get('format') if isinstance(head, dict) else None!r}, "
                         f"this FMU reads format {VERSION}")
    if head.get("identity") != identity:
        theirs = head.get("identity")
        diff = sorted(k for k in identity if not isinstance(theirs, dict) or theirs.get(k) != identity[k])
        raise StateError(f"the state of another FMU or build ({', '.join(diff) or 'identity'} "
                         f"{ {k: theirs.get(k) for k in diff} if isinstance(theirs, dict) else theirs!r} "
                         f"instead of { {k: identity[k] for k in diff} })")
    blob = body[n_header:]
    try:
        return _Decoder(head.get("arrays"), blob, bound, script, forbidden).node(head.get("tree"), 0)
    except StateError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError, OverflowError,
            RecursionError) as exc:
        raise StateError(f"malformed content: {type(exc).__name__}: {exc}") from None


class _Decoder:
    """The tree's nodes made objects (see :func:`decode`, whose ``arrays``, ``blob``, ``bound``,
    ``script`` and ``forbidden`` it holds)."""

    def __init__(self, arrays: Any, blob: memoryview, bound: Callable[[str], Any], script: str | None,
                 forbidden: tuple[type, ...]) -> None:
        if not isinstance(arrays, list):
            raise StateError("malformed content: no array table")
        self.arrays, self.blob, self.bound, self.script = arrays, blob, bound, script
        self.forbidden = forbidden
        self.ids: dict[int, Any] = {}

    def cls(self, name: Any) -> type:
        """The allowed class ``name`` (``module key:qualname``), found, never imported."""
        if not isinstance(name, str) or name.count(":") != 1:
            raise StateError(f"malformed class name {name!r}")
        key, qualname = name.split(":")
        if key == "@" and self.script is not None:
            module = self.script
        elif key.startswith("~") and (key == "~" or key.startswith("~.")):
            module = _PACKAGE + key[1:]
        else:
            raise StateError(f"class {name!r} is not one of this FMU's")
        found: Any = sys.modules.get(module)
        for part in qualname.split("."):
            space = getattr(found, "__dict__", None)     # a plain lookup: no __getattr__ runs
            found = space.get(part) if space is not None and hasattr(space, "get") else None
        if not (isinstance(found, type) and found.__module__ == module and found.__qualname__ == qualname):
            raise StateError(f"class {name!r} is not one of this FMU's")
        return found

    def identified(self, n: Any, value: Any) -> Any:
        if not isinstance(n, int) or n in self.ids:
            raise StateError(f"malformed content: node id {n!r} reused or not an integer")
        self.ids[n] = value
        return value

    def array(self, i: Any) -> np.ndarray:
        dtype, shape, order, start, size = self.arrays[i]
        if not (isinstance(dtype, str) and _DTYPE.fullmatch(dtype)):
            raise StateError(f"array of dtype {dtype!r}: only numbers are read")
        if not (isinstance(shape, list) and all(isinstance(d, int) and d >= 0 for d in shape)
                and order in ("C", "F") and isinstance(start, int) and isinstance(size, int)):
            raise StateError(f"malformed array entry {self.arrays[i]!r}")
        dt = np.dtype(dtype)
        count = 1
        for d in shape:
            count *= d
        if count * dt.itemsize != size or not 0 <= start <= start + size <= len(self.blob):
            raise StateError(f"array {i}: {size} bytes at {start} do not hold {shape} of {dt} "
                             f"within the {len(self.blob)} bytes given")
        return np.frombuffer(self.blob[start:start + size], dtype=dt).reshape(shape, order=order).copy(order="K")

    def node(self, x: Any, depth: int) -> Any:
        if depth > MAX_DEPTH:
            raise StateError(f"nested deeper than {MAX_DEPTH}")
        if not (isinstance(x, list) and x and isinstance(x[0], str)):
            raise StateError(f"malformed node {str(x)[:60]}")
        tag, args, d = x[0], x[1:], depth + 1
        if tag == "n" and not args:
            return None
        if tag == "b" and len(args) == 1 and type(args[0]) is bool:
            return args[0]
        if tag == "i" and len(args) == 1 and type(args[0]) is int:
            return args[0]
        if tag == "f" and len(args) == 1 and isinstance(args[0], str):
            return float.fromhex(args[0])
        if tag == "s" and len(args) == 1 and isinstance(args[0], str):
            return args[0]
        if tag == "x" and len(args) == 2 and isinstance(args[0], str) and _DTYPE.fullmatch(args[0]):
            dt = np.dtype(args[0])
            raw = bytes.fromhex(args[1])
            if len(raw) != dt.itemsize:
                raise StateError(f"a numpy scalar of {dt} with {len(raw)} bytes")
            return np.frombuffer(raw, dtype=dt)[0]
        if tag == "r" and len(args) == 1:
            if args[0] not in self.ids:
                raise StateError(f"reference to node {args[0]!r} before it")
            return self.ids[args[0]]
        if tag == "B" and len(args) == 1 and isinstance(args[0], str):
            try:
                return self.bound(args[0])
            except KeyError:
                raise StateError(f"unknown variable {args[0]!r}") from None
        if tag == "a" and len(args) == 2:
            return self.identified(args[1], self.array(args[0]))
        if tag == "t" and len(args) == 1 and isinstance(args[0], list):
            return tuple(self.node(v, d) for v in args[0])
        if tag == "T" and len(args) == 2 and isinstance(args[1], list):
            cls = self.cls(args[0])
            if not (issubclass(cls, tuple) and hasattr(cls, "_fields") and len(args[1]) == len(cls._fields)):
                raise StateError(f"class {args[0]!r} is not a named tuple of {len(args[1])} fields")
            return tuple.__new__(cls, [self.node(v, d) for v in args[1]])
        if tag == "l" and len(args) == 2 and isinstance(args[1], list):
            out: list = self.identified(args[0], [])
            out.extend(self.node(v, d) for v in args[1])
            return out
        if tag == "d" and len(args) == 2 and isinstance(args[1], list):
            out_d: dict = self.identified(args[0], {})
            for pair in args[1]:
                if not (isinstance(pair, list) and len(pair) == 2):
                    raise StateError("malformed dict entry")
                key = self.node(pair[0], d)
                if not isinstance(key, (type(None), bool, int, float, str, tuple)):
                    raise StateError(f"a dict key of type {type(key).__name__}")
                out_d[key] = self.node(pair[1], d)
            return out_d
        if tag == "g" and len(args) == 2:
            return self.identified(args[0], self.generator(self.node(args[1], d)))
        if tag == "o" and len(args) == 3 and isinstance(args[2], list):
            cls = self.cls(args[0])
            if not _plain(cls, self.forbidden):
                raise StateError(f"class {args[0]!r} is not a plain object")
            obj = self.identified(args[1], object.__new__(cls))
            attrs = obj.__dict__
            for pair in args[2]:
                if not (isinstance(pair, list) and len(pair) == 2 and isinstance(pair[0], str)):
                    raise StateError("malformed attribute entry")
                attrs[pair[0]] = self.node(pair[1], d)
            return obj
        raise StateError(f"unknown or malformed node {str(x)[:60]}")

    @staticmethod
    def generator(state: Any) -> np.random.Generator:
        """A ``numpy.random.Generator`` in ``state`` (its bit generator's ``state`` dict)."""
        name = state.get("bit_generator") if isinstance(state, dict) else None
        if name not in BIT_GENERATORS:
            raise StateError(f"a generator over {name!r}: only {', '.join(BIT_GENERATORS)} are read")
        bit_generator = getattr(np.random, name)()
        bit_generator.state = state        # numpy checks the dict (ValueError, TypeError)
        return np.random.Generator(bit_generator)


__all__ = ["MAGIC", "VERSION", "BIT_GENERATORS", "MAX_DEPTH", "StateError", "encode", "decode"]
