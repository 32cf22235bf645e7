"""Where a benchmark's figures come from: the checkout's commit and whether it had local changes, for the line each
bench prints above its table and the JSON it saves."""

from __future__ import annotations

import subprocess


def commit_and_dirty(root: str) -> tuple[str, bool]:
    """(short commit of HEAD, True when tracked files differ from it) of the checkout at ``root``; ("", False)
    outside a checkout or without git."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                text=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                                    capture_output=True, text=True).stdout.strip())
    except OSError:
        return "", False
    return commit, dirty
