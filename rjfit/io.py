"""Files in and out: strict JSON, and results written so that a reader sees the previous ones or
the new ones, never a mixture.

JSON: :func:`write_json_atomic` writes strict JSON (NaN and infinities as ``null``, NumPy
values as plain numbers) atomically; :func:`read_json` reads it, naming the file in its error.

Atomic writing has two levels:

- one file: :func:`atomic_path` yields a fresh temporary name beside the target; once the
  caller has written it, the file is flushed to disk (fsync) and renamed over the target. If
  the caller raises (a full disk, Ctrl-C, a ``savefig`` error) the temporary file is removed
  and the target is left as it was. :func:`write_text_atomic` and :func:`write_bytes_atomic`
  are the common cases.
- a folder of results that belong together (``rjfit fit``, ``diagnose``, ``compare``): they
  are written into a :func:`staging_dir` inside the output folder, then :func:`publish`
  moves them in with the manifest (``summary.json``, ``diagnosis.json``, ...) last, after
  removing the manifest and the previous run's files first. A folder without its manifest
  holds no results; one with it holds the results of that run only.

Before any expensive work a command calls :func:`check_writable` on its output folder, so that
a folder it cannot write is one line at the start (:class:`rjfit.errors.OutputError`), not a
traceback after the work; :func:`os_error_text` turns any other ``OSError`` into one line
naming the path.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import sys
import tempfile
from contextlib import contextmanager, suppress
from pathlib import Path

import numpy as np

from rjfit.errors import DatasetError, OutputError

__all__ = ["write_json_atomic", "read_json", "atomic_path", "write_text_atomic", "write_bytes_atomic", "staging_dir",
           "publish", "STAGING_PREFIX", "check_writable", "os_error_text", "raise_naming",
           "call_capturing_stderr"]

#: name prefix of staging folders; the creating process's id follows, so that a later run can
#: tell the leftover of a killed run from the staging folder of a run still going
STAGING_PREFIX = ".staging."


def _new_file_mode() -> int:
    """The mode ``open()`` gives a new file under this process's umask now (mkstemp gives 0600).

    Linux states the umask in ``/proc/self/status``; reading it there leaves it alone, where setting and
    restoring it (the only way elsewhere) would give another thread's new files the interim mask.
    """
    with suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return 0o666 & ~int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _fsync_file(path: Path) -> None:
    with open(path, "rb+") as handle:
        os.fsync(handle.fileno())


def _fsync_dir(path: Path) -> None:
    """Make renames and removals in ``path`` durable (POSIX; a no-op where a folder cannot be opened)."""
    if os.name == "nt":          # Windows cannot open a folder as a file; its renames are journalled
        return
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    except OSError as error:
        # some file systems (certain network and FUSE mounts) refuse fsync on a folder; the
        # renames are still atomic there, only not forced to disk at this point
        if error.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EBADF):
            raise
    finally:
        os.close(descriptor)


@contextmanager
def atomic_path(path):
    """Yield a unique temporary path in ``path``'s folder; on success it replaces ``path``.

    The caller writes the temporary path (by name: ``savefig``, ``write_text``, a library's
    writer). When the ``with`` block ends normally the file is given the usual mode of a new
    file, flushed to disk and renamed over ``path`` (atomic on POSIX and Windows). When the
    block raises, anything included (KeyboardInterrupt), the temporary file is removed and
    ``path`` is untouched. The folder is created if missing.

    Examples
    --------
    >>> with atomic_path(out / "figure.png") as temporary:      # doctest: +SKIP
    ...     figure.savefig(temporary, format="png")
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(descriptor)
    temporary = Path(name)
    replaced = False
    try:
        yield temporary
        os.chmod(temporary, _new_file_mode())
        _fsync_file(temporary)
        os.replace(temporary, path)
        replaced = True
    except OSError as error:
        raise_naming(error, path)
    finally:
        if not replaced:
            temporary.unlink(missing_ok=True)


def write_bytes_atomic(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    path = Path(path)
    with atomic_path(path) as temporary:
        temporary.write_bytes(data)
    return path


def write_text_atomic(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    path = Path(path)
    with atomic_path(path) as temporary:
        temporary.write_text(text, encoding=encoding)
    return path


def _owner_alive(folder: Path) -> bool:
    """Whether the process that made a staging folder (its id follows the prefix) still runs."""
    pid_text = folder.name[len(STAGING_PREFIX):].split(".", 1)[0]
    if not pid_text.isdigit():
        return False            # named by an rjfit that did not record its process id: a leftover
    if os.name == "nt":
        return True             # os.kill(pid, 0) would terminate the process there, not probe it
    try:
        os.kill(int(pid_text), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True             # alive, owned by another user
    except OSError:
        return True             # cannot tell: keep it rather than pull it from under a running run
    return True


@contextmanager
def staging_dir(out_dir):
    """A new, empty staging folder inside ``out_dir`` (created), removed with what is left in it
    when the ``with`` block ends, however it ends.

    Staging folders left by killed runs (whose process is gone) are removed first; those of
    runs still going are left alone. Inside ``out_dir``, so that :func:`publish` moves files
    by renaming within one file system.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for leftover in out_dir.glob(STAGING_PREFIX + "*"):
        if leftover.is_dir() and not _owner_alive(leftover):
            shutil.rmtree(leftover, ignore_errors=True)     # best effort: a leftover never blocks a run
    staging = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}.", dir=out_dir))
    try:
        yield staging
    except OSError as error:
        raise_naming(error, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)          # gone already once published, or a half-written run


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


def _fsync_tree(path: Path) -> None:
    if path.is_dir():
        for child in path.iterdir():
            _fsync_tree(child)
        _fsync_dir(path)
    elif path.is_file():
        _fsync_file(path)


def _plain_name(name) -> str:
    name = str(name)
    if not name or name in (".", "..") or Path(name).name != name:
        raise ValueError(f"{name!r}: a result is named by a plain file name in its folder")
    return name


def publish(staging, out_dir, *, manifest: str, names=None, remove=()) -> None:
    """Move a finished run's results from ``staging`` into ``out_dir``, manifest last.

    Parameters
    ----------
    staging : path
        Folder holding the new results (from :func:`staging_dir`).
    out_dir : path
        The output folder.
    manifest : str
        File that describes the results (``diagnosis.json``, ...): the previous one is removed
        first and the new one moved in last, so that a folder with a manifest never holds a
        mixture of two runs. ``staging`` must hold it.
    names : iterable of str, optional
        Entries of ``staging`` to move in (files or folders); default: all but the manifest.
        Names missing from ``staging`` are skipped.
    remove : iterable of str
        Entries of ``out_dir`` that the previous run wrote: removed before the new ones move in,
        so that none of them outlives its run.

    Raises
    ------
    FileNotFoundError
        If ``staging`` has no ``manifest``.
    ValueError
        If a name is not a plain file name (a path could reach outside ``out_dir``).
    """
    staging, out_dir = Path(staging), Path(out_dir)
    manifest = _plain_name(manifest)
    if not (staging / manifest).is_file():
        raise FileNotFoundError(f"{staging / manifest}: the results' manifest was not written; nothing published")
    if names is None:
        names = [entry.name for entry in staging.iterdir() if entry.name != manifest]
    names = [_plain_name(name) for name in names if _plain_name(name) != manifest]
    remove = [_plain_name(name) for name in remove]
    # the new files reach the disk before any old one goes
    for name in names + [manifest]:
        _fsync_tree(staging / name)
    (out_dir / manifest).unlink(missing_ok=True)
    _fsync_dir(out_dir)
    for name in dict.fromkeys(remove + names):
        if name != manifest:
            _remove(out_dir / name)
    for name in names:
        if (staging / name).exists():
            os.replace(staging / name, out_dir / name)
    _fsync_dir(out_dir)
    os.replace(staging / manifest, out_dir / manifest)
    _fsync_dir(out_dir)


# -- can the output be written? ---------------------------------------------------------------

def _result_path(name) -> str:
    """``name`` as the result it is written for: a staging folder's part dropped
    (``OUT/.staging.123.x/figures/a.png`` is ``OUT/figures/a.png``)."""
    parts = Path(name).parts
    return str(Path(*[part for part in parts if not part.startswith(STAGING_PREFIX)])) if parts else str(name)


def os_error_text(error: OSError) -> str:
    """One line for an ``OSError``: ``PATH: reason`` (``PATH -> TARGET: reason`` for a rename), a
    path inside a staging folder given as the result it is written for; the error's own text
    where it names no path (rjfit's errors, which name it themselves)."""
    if error.filename is None or isinstance(error, OutputError):
        return str(error)
    where = _result_path(error.filename)
    if error.filename2 is not None:
        where += f" -> {_result_path(error.filename2)}"
    return f"{where}: {error.strerror or error}"


def raise_naming(error: OSError, path) -> None:
    """Raise ``error``; one that names no file (``write()`` on a full disk names none) as the same
    kind of error naming ``path``, the file or folder being written."""
    if error.filename is not None:
        raise error
    raise OSError(error.errno, error.strerror or str(error), str(path)) from error


def _blocking_file(folder: Path) -> Path | None:
    """The nearest ancestor of ``folder`` (or ``folder`` itself) that exists and is not a folder."""
    for path in (folder, *folder.parents):
        if os.path.lexists(path):
            return None if path.is_dir() else path
    return None


def check_writable(folder, *, keep: bool = False) -> Path:
    """Check that results can be written in ``folder``, before any expensive work.

    Creates the missing folders, writes and removes a probe file in ``folder``, then (unless
    ``keep``) removes the folders it created, so the file system is left as it was. A root user
    passes permission checks, but not a path under a file (``--out FILE/sub``) or a full disk.

    Parameters
    ----------
    folder : path-like
        The output folder (it need not exist).
    keep : bool
        Leave the folder created (the caller writes into it next).

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    OutputError
        If the folder cannot be created or a file cannot be written in it; the message names
        the folder and why (the file in the way, no permission, a full disk).
    """
    folder = Path(folder)
    missing = [path for path in (folder, *folder.parents) if not os.path.lexists(path)]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        descriptor, probe = tempfile.mkstemp(dir=folder, prefix=".rjfit-probe.")
        try:
            os.write(descriptor, b"rjfit")      # a full disk refuses data, not always the name
        finally:
            os.close(descriptor)
            os.unlink(probe)
    except OSError as error:
        blocking = _blocking_file(folder)
        reason = f"{blocking} is a file, not a folder" if blocking is not None else error.strerror or str(error)
        raise OutputError(f"{folder}: cannot write results there ({reason})") from None
    finally:
        for path in [] if keep and folder.is_dir() else missing:      # deepest first
            with suppress(OSError):
                path.rmdir()
    return folder


# -- C libraries' messages -----------------------------------------------------------------------

def call_capturing_stderr(function, *args):
    """``(function(*args), text)``: what C libraries wrote to standard error meanwhile, captured.

    A decoder such as libpng prints ``libpng error: ...`` on file descriptor 2 before it
    returns a failure (OpenCV then gives None). Captured, the text becomes part of the one
    line that names the file, instead of library noise before it. The capture swaps file
    descriptor 2 for a temporary file for the call (the process's other threads' messages
    meanwhile are captured too: a caller whose call succeeds writes the text back).
    """
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:             # no standard error to capture (closed): nothing to keep quiet
        return function(*args), ""
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                result = function(*args)
            finally:
                os.dup2(saved, 2)
            sink.seek(0)
            text = sink.read().decode("utf-8", errors="replace").strip()
    finally:
        os.close(saved)
    return result, text


# -- strict JSON ------------------------------------------------------------------------------

def write_json_atomic(path, payload) -> None:
    """Write JSON so that readers see the old file or the new one, never half of one.

    NaN and infinities (an R-hat that cannot be computed) are written as ``null``: Python
    would write ``NaN``, which is not JSON and which other languages' parsers reject.
    """
    write_text_atomic(Path(path), json.dumps(_finite_or_null(payload), indent=1, sort_keys=False,
                                             default=_json_default, allow_nan=False))


def _finite_or_null(value):
    if isinstance(value, dict):
        return {key: _finite_or_null(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(item) for item in value]
    if isinstance(value, np.ndarray):
        return _finite_or_null(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def read_json(path):
    """A JSON file's content (any JSON value; callers check its shape).

    Parameters
    ----------
    path : path-like
        The JSON file.

    Returns
    -------
    object
        The parsed value (dict, list, str, number, bool or None).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    DatasetError
        If the file does not parse as JSON, is not UTF-8 text, or cannot be read (a folder,
        no permission); the message names it.
    """
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise DatasetError(f"{path}: not valid JSON ({error}); was it truncated or edited by hand?") from None
    except FileNotFoundError:
        raise
    except (UnicodeDecodeError, OSError) as error:
        raise DatasetError(f"{path}: not a readable JSON text file ({error})") from None
