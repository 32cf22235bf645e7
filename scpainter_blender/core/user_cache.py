"""The user's cache folder, for what must never be written into the add-on's own folder (an installed extension may
be read-only or shared). stdlib only: ``python -m backend`` sets ``NUMBA_CACHE_DIR`` from it before anything else,
so ``doctor`` still runs, and says what is missing, in an interpreter without numpy."""

from __future__ import annotations

import os


def user_cache_dir(*parts: str) -> str:
    """``$XDG_CACHE_HOME/scpainter/<parts>`` (``~/.cache/scpainter/...`` without it)."""
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(cache, "scpainter", *parts)
