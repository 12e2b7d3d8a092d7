"""Where Numba keeps rjfit's compiled functions: a folder per version of rjfit's source.

Why: Numba's on-disk cache (``cache=True``) checks only the source file of the function it compiled, not the
files of the functions it calls and inlines. A compiled label sweep (``passes/labels.py``) kept the edge term of
``passes/edges.py`` as it was when the sweep was first compiled, and went on using it after the edge term changed
(found 2026-11-28: on the development machine the label sweep's delayed acceptance had held an edge term older
than the other moves' since the afternoon, so those chains were not exact for the documented target; a fresh
clone compiles afresh and was not affected; docs/results/2026-11-28-local-gain.md). Keying the cache's folder on
every source file of the package makes any change compile everything afresh once.

A ``NUMBA_CACHE_DIR`` the user set is kept. Without a writable cache folder Numba's own default applies. Each
version's folder holds some 30 MB, so when a new one is made the least recently used beyond the newest
:data:`KEPT_VERSIONS` are removed.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
from pathlib import Path

__all__ = ["source_key", "use_source_keyed_cache", "prune_versions", "KEPT_VERSIONS"]

#: cache folders kept per user: the running version's and the most recently used others (a second checkout or
#: an older install in use beside this one keeps its compiled functions)
KEPT_VERSIONS = 4

_KEY = re.compile(r"[0-9a-f]{16}")


def source_key(package_dir) -> str:
    """A short hash of every ``.py`` file under ``package_dir``: their paths relative to it and their contents."""
    root = Path(package_dir)
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def use_source_keyed_cache(package_dir=None, environ=None) -> str | None:
    """Point Numba's cache at ``<user cache>/rjfit/numba/<source key>`` unless ``NUMBA_CACHE_DIR`` is set; return
    the folder used (None: the user's, or Numba's default where the folder cannot be made).

    Called by ``import rjfit`` before any of its compiled functions is defined. The user cache is
    ``$XDG_CACHE_HOME`` or ``~/.cache``. The variable is set in ``environ`` (default ``os.environ``), so that the
    chains' worker processes use the same folder, and on ``numba.config`` where Numba is already imported.
    """
    environ = os.environ if environ is None else environ
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    package_dir = Path(__file__).resolve().parent if package_dir is None else Path(package_dir)
    base = Path(environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = base / "rjfit" / "numba" / source_key(package_dir)
    made = not folder.is_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)    # its use, for prune_versions' recency
    except OSError:         # a read-only home: Numba's default (next to the sources) applies
        return None
    if made:
        prune_versions(folder.parent, keep=KEPT_VERSIONS)
    environ["NUMBA_CACHE_DIR"] = str(folder)
    numba = sys.modules.get("numba")
    if numba is not None:
        numba.config.CACHE_DIR = str(folder)
    return str(folder)


def prune_versions(parent, keep: int = KEPT_VERSIONS) -> list[str]:
    """Remove the version folders under ``parent`` (16-hex-digit names, as :func:`use_source_keyed_cache` makes
    them) beyond the ``keep`` most recently used (by modification time); return the names removed.

    Anything else under ``parent`` is left alone. A folder that cannot be removed (another user's, or in use on a
    file system that refuses) stays, and is not named: only a slower first import elsewhere depends on it.
    """
    versions = sorted((path for path in Path(parent).iterdir() if path.is_dir() and _KEY.fullmatch(path.name)),
                      key=lambda path: path.stat().st_mtime, reverse=True)
    removed = []
    for path in versions[keep:]:
        try:
            shutil.rmtree(path)
        except OSError:     # the cache is an optimisation: a folder left behind costs disk, never a result
            continue
        removed.append(path.name)
    return removed
