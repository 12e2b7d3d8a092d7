"""rjfit.io and its users: a write that fails leaves the previous file whole and no temporary
file; staging folders of killed runs are cleared, those of running ones kept; a folder is
published with its manifest last; the report page and figures are written through them."""
from __future__ import annotations

import errno
import json
import os
import subprocess
import sys

import pytest

from rjfit.io import (STAGING_PREFIX, atomic_path, os_error_text, publish, staging_dir, write_bytes_atomic,
                      write_text_atomic)


def _files(folder):
    return sorted(path.name for path in folder.iterdir())


def _umask_mode():
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def test_atomic_path_replaces_the_file_with_the_usual_mode(tmp_path):
    target = tmp_path / "sub" / "result.txt"
    write_text_atomic(target, "first")
    write_bytes_atomic(target, b"second")
    assert target.read_bytes() == b"second" and _files(target.parent) == ["result.txt"]
    # mkstemp makes 0600 files: the result gets the mode a plain open() would give it
    assert target.stat().st_mode & 0o777 == _umask_mode()


def test_a_umask_changed_between_writes_gives_the_later_file_the_mode_open_gives(tmp_path):
    write_text_atomic(tmp_path / "first.txt", "first")
    old = os.umask(0o077)
    try:
        write_text_atomic(tmp_path / "second.txt", "second")
        (tmp_path / "plain.txt").write_text("plain")
    finally:
        os.umask(old)
    assert (tmp_path / "second.txt").stat().st_mode & 0o777 == (tmp_path / "plain.txt").stat().st_mode & 0o777 == 0o600


@pytest.mark.parametrize("error", [OSError("No space left on device"), KeyboardInterrupt()])
def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path, error):
    target = tmp_path / "result.json"
    target.write_text("old")
    with pytest.raises(type(error)):
        with atomic_path(target) as temporary:
            assert temporary.parent == tmp_path and temporary.name != target.name
            temporary.write_text("half of the n")
            raise error
    assert target.read_text() == "old" and _files(tmp_path) == ["result.json"]


def test_temporary_names_are_unique_per_write(tmp_path):
    """Two writers of one file (two diagnoses into one folder) never share a temporary file."""
    target = tmp_path / "diagnosis.md"
    with atomic_path(target) as first, atomic_path(target) as second:
        assert first != second
        first.write_text("one")
        second.write_text("two")
    assert target.read_text() == "one" and _files(tmp_path) == ["diagnosis.md"]


def test_text_that_cannot_be_encoded_leaves_no_temporary(tmp_path):
    target = tmp_path / "report.html"
    target.write_text("old")
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(target, "a lone surrogate \ud800")
    assert target.read_text() == "old" and _files(tmp_path) == ["report.html"]


def test_save_figure_that_fails_leaves_the_old_png_and_closes_the_figure(tmp_path, monkeypatch):
    from rjfit.plotting import pyplot, save_figure

    plt = pyplot()
    target = tmp_path / "map.png"
    figure, axis = plt.subplots()
    axis.plot([0, 1], [0, 1])
    save_figure(figure, target)
    old = target.read_bytes()
    assert old[:8] == b"\x89PNG\r\n\x1a\n" and figure.number not in plt.get_fignums()

    figure, axis = plt.subplots()
    axis.plot([0, 1], [1, 0])

    def broken_savefig(path, **kwargs):
        with open(path, "wb") as handle:
            handle.write(b"\x89PNG half")
        raise OSError("No space left on device")

    monkeypatch.setattr(figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="No space"):
        save_figure(figure, target)
    assert target.read_bytes() == old and _files(tmp_path) == ["map.png"]
    assert figure.number not in plt.get_fignums(), "a failed save leaves the figure open"


def test_report_page_that_cannot_be_written_leaves_the_old_one(tmp_path):
    from rjfit.pipeline.report import build_report

    fit_dir = tmp_path / "fit"
    fit_dir.mkdir()
    (fit_dir / "summary.json").write_text(json.dumps({"warnings": ["R-hat max 1.2"]}))
    build_report(fit_dir)
    old = (fit_dir / "report.html").read_text()
    assert "R-hat max 1.2" in old
    # a summary whose text cannot be written as UTF-8 fails while the page is written
    (fit_dir / "summary.json").write_text(json.dumps({"warnings": ["\ud800"]}))
    with pytest.raises(UnicodeEncodeError):
        build_report(fit_dir)
    assert (fit_dir / "report.html").read_text() == old
    assert _files(fit_dir) == ["report.html", "summary.json"]


def test_staging_dir_clears_leftovers_of_dead_runs_only(tmp_path):
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True)
    dead = tmp_path / f"{STAGING_PREFIX}{finished.stdout.strip()}.abc"
    legacy = tmp_path / f"{STAGING_PREFIX}killed"               # an older rjfit's name: no process id
    running = tmp_path / f"{STAGING_PREFIX}{os.getppid()}.xyz"  # this test's parent process still runs
    for folder in (dead, legacy, running):
        (folder / "figures").mkdir(parents=True)
    with staging_dir(tmp_path) as staging:
        assert staging.is_dir() and staging.name.startswith(f"{STAGING_PREFIX}{os.getpid()}.")
        assert not dead.exists() and not legacy.exists() and running.is_dir()
        (staging / "half.png").write_bytes(b"half")
    assert not staging.exists() and running.is_dir()


def test_publish_moves_the_manifest_last_and_removes_the_previous_run(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("result.json", "old_figure.png", "kept_by_user.txt"):
        (out / name).write_text("previous run")
    staging = tmp_path / "staging"
    staging.mkdir()
    (staging / "result.json").write_text("new manifest")
    (staging / "new_figure.png").write_text("new figure")
    seen = []
    real_replace = os.replace

    def recording_replace(source, target):
        # whenever a file moves in, the previous manifest and the previous run's files are gone
        assert not (out / "result.json").exists() and not (out / "old_figure.png").exists()
        seen.append(os.path.basename(target))
        return real_replace(source, target)

    monkeypatch.setattr(os, "replace", recording_replace)
    publish(staging, out, manifest="result.json", remove=["old_figure.png"])
    assert seen == ["new_figure.png", "result.json"]
    assert _files(out) == ["kept_by_user.txt", "new_figure.png", "result.json"]
    assert (out / "result.json").read_text() == "new manifest" and not list(staging.iterdir())


def test_publish_refuses_names_outside_the_folder_and_a_missing_manifest(tmp_path):
    staging = tmp_path / "staging"
    staging.mkdir()
    with pytest.raises(FileNotFoundError, match="manifest was not written"):
        publish(staging, tmp_path, manifest="result.json")
    (staging / "result.json").write_text("{}")
    with pytest.raises(ValueError, match="plain file name"):
        publish(staging, tmp_path / "out", manifest="result.json", remove=["../elsewhere"])
    assert (staging / "result.json").is_file()


def test_maps_of_a_small_object_are_shown_in_its_window(tmp_path):
    """map_figure zooms to the finite pixels plus a margin; axes keep the files' pixel coordinates."""
    import numpy as np

    from rjfit.plotting import object_window, pyplot, zoom_to_object

    mask = np.zeros((512, 612), bool)
    mask[200:341, 250:391] = True                       # a ball-sized object in a DiLiGenT-sized frame
    assert object_window(mask) == (slice(197, 344), slice(247, 394))
    edge = np.zeros((10, 12), bool)
    edge[0:2, 10:12] = True                             # the margin stops at the image's borders
    assert object_window(edge) == (slice(0, 5), slice(7, 12))
    assert object_window(np.zeros((4, 4), bool)) is None
    plt = pyplot()
    figure, axis = plt.subplots()
    axis.imshow(np.where(mask, 1.0, np.nan))
    zoom_to_object(axis, mask)
    assert axis.get_xlim() == (246.5, 393.5) and axis.get_ylim() == (343.5, 196.5)
    untouched = axis.get_xlim(), axis.get_ylim()
    zoom_to_object(axis, np.zeros_like(mask))           # nothing to show: limits left as they were
    assert (axis.get_xlim(), axis.get_ylim()) == untouched
    plt.close(figure)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux), a device that is always full")
def test_a_full_disk_is_one_line_naming_the_result_being_written(tmp_path):
    """``write()`` on a full disk raises ENOSPC naming no file: the staging folder and the atomic
    file name the result it was for (not the staging path), and leave nothing behind. /dev/full
    gives the real error, for any user."""
    out = tmp_path / "out"
    with pytest.raises(OSError) as caught:
        with staging_dir(out) as staging, atomic_path(staging / "figures" / "a.png"):
            with open("/dev/full", "wb") as full:
                full.write(b"results")
    assert caught.value.errno == errno.ENOSPC
    assert os_error_text(caught.value) == f"{out / 'figures' / 'a.png'}: No space left on device"
    assert list(out.iterdir()) == []
