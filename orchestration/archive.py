"""Bounded archives: the limits every FMU and SSP package (zip archives) is checked against
before anything of it is extracted or read, from the zip's central directory alone.

An archive is refused (:class:`ArchiveError`, one message naming the archive, the limit and
the variable that overrides it) if

* its entries' uncompressed sizes add up to more than :data:`MAX_BYTES` (default 1 GiB;
  ``FLEXFUSION_ARCHIVE_MAX_BYTES``, in bytes), or
* it has more than :data:`MAX_ENTRIES` entries (default 10,000; ``FLEXFUSION_ARCHIVE_MAX_ENTRIES``), or
* one entry of more than :data:`RATIO_FROM_BYTES` (1 MiB) expands more than :data:`MAX_RATIO`
  times its compressed size (default 200; ``FLEXFUSION_ARCHIVE_MAX_RATIO``): compiled
  libraries deflate about 3 to 1, text about 10 to 1, a file of zeros 1000 to 1; or
* an entry's name leaves the folder it is extracted to (an absolute path, a drive, ``..``).

The sizes are those the central directory declares; Python's ``zipfile`` never writes more than
the declared size of an entry (and checks its CRC), so the declared total bounds what
extraction writes. Our FMUs are about 3-10 MB and a few hundred entries, far inside.
"""
from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Iterable

MAX_BYTES = 1 << 30          #: default limit on an archive's total uncompressed size [bytes]
MAX_ENTRIES = 10_000         #: default limit on an archive's number of entries
MAX_RATIO = 200.0            #: default limit on an entry's compression ratio (uncompressed / compressed)
RATIO_FROM_BYTES = 1 << 20   #: the ratio is checked on entries larger than this [bytes]

_ENV = {"max_bytes": "FLEXFUSION_ARCHIVE_MAX_BYTES", "max_entries": "FLEXFUSION_ARCHIVE_MAX_ENTRIES",
        "max_ratio": "FLEXFUSION_ARCHIVE_MAX_RATIO"}


class ArchiveError(ValueError):
    """An archive beyond a limit or with an unsafe entry name; the message names the archive."""


@dataclass(frozen=True)
class Limits:
    """The limits of an archive: ``max_bytes`` total uncompressed size, ``max_entries`` entries,
    ``max_ratio`` compression ratio of an entry over :data:`RATIO_FROM_BYTES`."""
    max_bytes: int = MAX_BYTES
    max_entries: int = MAX_ENTRIES
    max_ratio: float = MAX_RATIO


def limits() -> Limits:
    """The limits in force: the defaults, each overridden by its environment variable
    (``FLEXFUSION_ARCHIVE_MAX_BYTES``, ``..._MAX_ENTRIES``, ``..._MAX_RATIO``).

    Raises
    ------
    ArchiveError
        A variable that is not a positive number.
    """
    values: dict[str, float] = {}
    for field, var in _ENV.items():
        text = os.environ.get(var, "").strip()
        if not text:
            continue
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not value > 0 or value == float("inf"):
            raise ArchiveError(f"{var}={text!r}: not a positive number")
        values[field] = value if field == "max_ratio" else int(value)
    return Limits(**values)  # type: ignore[arg-type]


def check(members: Iterable[zipfile.ZipInfo], label: str, bounds: Limits | None = None) -> None:
    """Refuse the archive ``label`` whose central directory lists ``members`` if it passes a
    limit (``bounds``, default :func:`limits`) or an entry's name leaves its folder.

    Raises
    ------
    ArchiveError
        Naming the archive, the limit passed and the environment variable that sets it.
    """
    bounds = bounds or limits()
    members = list(members)
    if len(members) > bounds.max_entries:
        raise ArchiveError(f"{label}: {len(members)} entries, more than the limit of {bounds.max_entries} "
                           f"(set {_ENV['max_entries']} to allow more)")
    total = 0
    for m in members:
        name = m.filename
        parts = PurePosixPath(name.replace("\\", "/")).parts
        if name.startswith(("/", "\\")) or ".." in parts or (parts and ":" in parts[0]):
            raise ArchiveError(f"{label}: unsafe entry name {name!r} (it leaves the folder it is extracted to)")
        total += m.file_size
        if m.file_size > RATIO_FROM_BYTES and m.file_size > bounds.max_ratio * max(m.compress_size, 1):
            raise ArchiveError(f"{label}: entry {name!r} expands {m.file_size / max(m.compress_size, 1):.0f} "
                               f"times ({m.compress_size} to {m.file_size} bytes), more than the limit of "
                               f"{bounds.max_ratio:g} (set {_ENV['max_ratio']} to allow more)")
    if total > bounds.max_bytes:
        raise ArchiveError(f"{label}: {total} bytes uncompressed, more than the limit of {bounds.max_bytes} "
                           f"(set {_ENV['max_bytes']} to allow more)")


def checked(z: zipfile.ZipFile, label: str) -> zipfile.ZipFile:
    """The open archive ``z`` once :func:`check` passed on its central directory."""
    check(z.infolist(), label)
    return z


__all__ = ["ArchiveError", "Limits", "limits", "check", "checked", "MAX_BYTES", "MAX_ENTRIES", "MAX_RATIO",
           "RATIO_FROM_BYTES"]
