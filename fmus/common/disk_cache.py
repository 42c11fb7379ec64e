"""Where FlexFusion keeps, across processes, what it computes once and finds again by content.

``$FLEXFUSION_CACHE_DIR``, else ``$XDG_CACHE_HOME/flexfusion``, else ``~/.cache/flexfusion``
(the root the kernel cache of :mod:`fmus.common.jit` uses too). Every entry is named by a
hash of everything it is made from, and published whole (written under a temporary name, then
renamed), so a reader never sees a half-written entry and no entry is ever stale; a folder
that cannot be written means no cache (the caller computes), never an error.
"""
from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """The cache's root folder (see the module docstring; it may not exist yet)."""
    base = os.environ.get("FLEXFUSION_CACHE_DIR")
    if not base:
        base = os.path.join(os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache"), "flexfusion")
    return Path(base)
