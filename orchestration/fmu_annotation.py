"""What an FMU says about itself: the FlexFusion vendor annotation of its modelDescription.

Every FlexFusion FMU declares its role, its batched kernel (if any) and the default search
ranges of its tunable parameters on its class (:class:`fmus.common.fmi.FlexFusionSlave`), and the
build writes them into the modelDescription as ``<VendorAnnotations><Tool name="flexfusion">``;
a third-party FMU may carry the same annotation (the schema: docs/fmu_annotation.md). The
orchestration reads them here, never from a list of model identifiers: the honest-signals rule
and the judge (:mod:`orchestration.roles`, :mod:`orchestration.judge`), the tuner's default
bounds (:mod:`orchestration.study_tune`) and the batched engine (:mod:`orchestration.batched`).
An FMU without the annotation is an estimator, with no default bounds and no batched kernel.
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

#: The tool name of the annotation and the schema versions this reader knows.
TOOL = "flexfusion"
VERSIONS = ("1",)
#: The roles a component may declare (the same as fmus.common.fmi.ROLES, not imported: a run
#: never imports the working tree's fmus; tests/test_fmu_annotation.py checks they agree).
ROLES = ("plant", "environment", "sensor", "reference", "controller", "estimator", "log")
#: The role of an FMU without the annotation.
DEFAULT_ROLE = "estimator"
ANNOTATIONS_KEPT = 256      # disk cache entries (one per FMU content)


class AnnotationError(ValueError):
    """A malformed FlexFusion vendor annotation; the message names the FMU and the cause."""


@dataclass(frozen=True)
class SelfDescription:
    """The annotation of one FMU.

    Parameters
    ----------
    role
        One of :data:`ROLES`.
    batched
        Name of its batched kernel in :mod:`orchestration.batched`, or None.
    search
        Default search range ``(low, high)`` of the tuner per scalar parameter name, in the
        FMU's declaration order.
    annotated
        Whether the FMU carries the annotation (False: the defaults above).
    """
    role: str = DEFAULT_ROLE
    batched: str | None = None
    search: dict[str, tuple[float, float]] = field(default_factory=dict)
    annotated: bool = False


_MEMO: dict[str, SelfDescription] = {}


def describe(fmu: Path | str) -> SelfDescription:
    """The self-description of the FMU file ``fmu``, parsed once per FMU content (kept in the
    FMU store's cache as the model descriptions are, :func:`orchestration.fmu_store.described`).

    Raises
    ------
    AnnotationError
        A malformed annotation (unknown role or version, a bad range).
    """
    from . import fmu_store
    fmu = Path(fmu)
    key = fmu_store.content_key(fmu)
    if key not in _MEMO:
        row = fmu_store.described(fmu, "fmu_annotations", _parse, ANNOTATIONS_KEPT)
        _MEMO[key] = SelfDescription(row["role"], row["batched"],
                                     {n: (float(lo), float(hi)) for n, lo, hi in row["search"]},
                                     row["annotated"])
    return _MEMO[key]


def describe_entry(doc: dict[str, Any], component: str) -> SelfDescription:
    """The self-description of a component of a scenario document
    (:func:`orchestration.scenario.scenario_document`: its ``fmu`` is a model identifier looked up
    in :func:`orchestration.scenario.fmu_dir`, or an absolute path); the defaults when that file
    does not exist (loading the scenario says so)."""
    from .scenario import fmu_dir
    spec = str(doc["components"][component].get("fmu", ""))
    path = Path(spec) if spec.endswith(".fmu") or "/" in spec else fmu_dir() / f"{spec}.fmu"
    return describe(path) if path.is_file() else SelfDescription()


def _parse(fmu: Path) -> dict[str, Any]:
    """:func:`describe`'s fields from the modelDescription (JSON for the disk cache)."""
    with zipfile.ZipFile(fmu) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    comp = root.find(f"VendorAnnotations/Tool[@name='{TOOL}']/Component")         # FMI 2.0
    if comp is None:
        comp = root.find(f"Annotations/Annotation[@type='{TOOL}']/Component")     # FMI 3.0
    if comp is None:
        return {"role": DEFAULT_ROLE, "batched": None, "search": [], "annotated": False}
    where = f"{fmu}: <Tool name=\"{TOOL}\"> annotation"
    version = comp.get("version")
    if version not in VERSIONS:
        raise AnnotationError(f"{where}: version {version!r} is not one of {', '.join(VERSIONS)}")
    role = comp.get("role", DEFAULT_ROLE)
    if role not in ROLES:
        raise AnnotationError(f"{where}: role {role!r} is not one of {', '.join(ROLES)}")
    search = []
    for tune in comp.findall("Tune"):
        name = tune.get("name")
        try:
            low, high = float(tune.get("low")), float(tune.get("high"))
        except (TypeError, ValueError):
            raise AnnotationError(f"{where}: <Tune name={name!r}> needs numbers low and high") from None
        if not name or not low < high:
            raise AnnotationError(f"{where}: <Tune name={name!r} low={low} high={high}> needs a "
                                  "name and low < high")
        search.append([name, low, high])
    return {"role": role, "batched": comp.get("batched"), "search": search, "annotated": True}


__all__ = ["ANNOTATIONS_KEPT", "AnnotationError", "DEFAULT_ROLE", "ROLES", "SelfDescription", "TOOL",
           "VERSIONS", "describe", "describe_entry"]
