"""Outputs that cannot be written: every command says so in one line before any work, and a fit
whose results cannot be written after sampling keeps its chains and publishes them when run again.

The failures are real OS errors, not mocks: a path under a regular file (NotADirectoryError,
also for root), a folder this process cannot write (chmod 0o555; for root, whom permissions do
not stop, the immutable attribute, skipped where the file system or the user cannot set it), and
a folder where the fit must write its ``summary.json`` file (IsADirectoryError at the very end).
"""
import json
import os
import shutil
import subprocess
import sys

import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.errors import OutputError
from rjfit.io import check_writable


@pytest.fixture
def locked(tmp_path):
    """A folder this process cannot create files in."""
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    immutable = False
    if os.access(folder, os.W_OK):     # root: permissions do not stop it; the immutable attribute does
        immutable = subprocess.run(["chattr", "+i", str(folder)], capture_output=True, check=False).returncode == 0 \
            if shutil.which("chattr") else False
        if not immutable:
            folder.chmod(0o755)
            pytest.skip("cannot make a folder unwritable here (root, and no chattr +i on this file system)")
    yield folder
    if immutable:
        subprocess.run(["chattr", "-i", str(folder)], check=True)
    folder.chmod(0o755)


@pytest.fixture
def a_file(tmp_path):
    path = tmp_path / "a_file"
    path.write_text("not a folder\n")
    return path


def test_check_writable_leaves_the_file_system_as_it_was(tmp_path):
    target = tmp_path / "new" / "deeper"
    assert check_writable(target) == target
    assert not (tmp_path / "new").exists()          # it created, probed and removed both folders
    check_writable(target, keep=True)
    assert target.is_dir() and list(target.iterdir()) == []       # kept, without the probe


def test_check_writable_names_the_file_in_the_way(a_file):
    with pytest.raises(OutputError, match=f"^{a_file}/sub/deeper: cannot write results there \\({a_file} is a file, "
                                          f"not a folder\\)$"):
        check_writable(a_file / "sub" / "deeper")


def test_check_writable_refuses_a_locked_folder(locked):
    with pytest.raises(OutputError, match=f"^{locked}/fit: cannot write results there \\((Permission denied|"
                                          f"Operation not permitted)\\)$"):
        check_writable(locked / "fit")
    assert list(locked.iterdir()) == []


def _commands(dataset, out):
    """Each command with its output at ``out`` (``report`` writes a file there)."""
    return {"render": ["render", "paper_sphere", "--out", str(out), "--resolution", "8"],
            "validate": ["validate", str(dataset), "--out", str(out)],
            "fit": ["fit", str(dataset), "--out", str(out), "--iterations", "20", "--chains", "1"],
            "compare": ["compare", str(dataset), "--out", str(out)],
            "diagnose": ["diagnose", str(dataset), "--out", str(out)],
            "refine": ["refine", str(dataset), "--out", str(out)],
            "report": ["report", str(dataset), "--out", str(out / "report.html")],
            "run": ["run", "paper_sphere", "--out", str(out), "--resolution", "8", "--iterations", "20"]}


@pytest.mark.parametrize("command", ["render", "validate", "fit", "compare", "diagnose", "refine", "report", "run"])
def test_every_command_refuses_an_out_under_a_file_in_one_line_before_any_work(command, paper_sphere_small, a_file):
    """`--out FILE/sub`: one line naming the path and the file in the way, exit status 1, no
    traceback, nothing written. diagnose, refine and report are given a data set, not a fit
    folder: the output is checked before their input is read."""
    out = a_file / "sub"
    result = CliRunner().invoke(main, _commands(paper_sphere_small, out)[command])
    folder = out if command != "render" else a_file
    assert result.exit_code == 1, result.output
    assert result.output.splitlines() == [f"Error: {folder}: cannot write results there ({a_file} is a file, not a "
                                          f"folder)"], result.output


@pytest.mark.parametrize("command", ["validate", "fit", "compare", "report"])
def test_a_locked_folder_is_refused_in_one_line_before_any_work(command, paper_sphere_small, locked):
    result = CliRunner().invoke(main, _commands(paper_sphere_small, locked / "out")[command])
    assert result.exit_code == 1, result.output
    lines = result.output.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {locked / 'out'}: cannot write results there ("), lines
    assert list(locked.iterdir()) == []


def test_a_fit_whose_results_cannot_be_written_keeps_its_chains_and_publishes_them_when_run_again(
        paper_sphere_small, tmp_path):
    """A folder stands where the fit must write ``summary.json``: every chain samples, then the
    publish fails (IsADirectoryError, a real OS error after the work, like a disk filled by then).
    The command says so in one line naming the path, how to publish the chains, and exits 1;
    the chains' final checkpoints stay, no result file or staging folder does. Once the folder is
    gone, the same command resumes every chain at its last iteration (no sampling) and publishes
    the results of an uninterrupted fit."""
    def command(out):
        return [sys.executable, "-m", "rjfit", "fit", str(paper_sphere_small), "--out", str(out), "--chains", "2",
                "--iterations", "40", "--seed", "3", "--allow-unvalidated"]

    whole = tmp_path / "whole"
    subprocess.run(command(whole), check=True, capture_output=True)
    out = tmp_path / "blocked"
    (out / "summary.json").mkdir(parents=True)
    failed = subprocess.run(command(out), capture_output=True, text=True, check=False)
    assert failed.returncode == 1
    error_lines = [line for line in failed.stderr.splitlines() if line.startswith("Error")]
    assert error_lines == [
        f"Error: {out / 'summary.json'}: Is a directory; the fit's results were not written ({out} keeps its previous "
        f"ones, if any); the sampled chains are kept in {out / 'checkpoints'}: once that is fixed, run the same "
        f"command again to publish them without sampling again"], failed.stderr
    assert "Traceback" not in failed.stderr + failed.stdout
    assert sorted(path.name for path in out.iterdir()) == ["checkpoints", "summary.json"]
    assert sorted(path.name for path in (out / "checkpoints").iterdir()) == ["chain_0.pkl", "chain_1.pkl"]

    (out / "summary.json").rmdir()
    rerun = subprocess.run(command(out), check=True, capture_output=True, text=True)
    for chain in (0, 1):
        assert f"chain {chain}: resumed from its checkpoint at iteration 40 of 40" in rerun.stderr
    assert not (out / "checkpoints").exists()
    published, uninterrupted = (json.loads((folder / "summary.json").read_text()) for folder in (out, whole))
    assert published["chain_resumed_from"] == [[40], [40]]
    timings = {"seconds", "chain_seconds", "chain_resumed_from"}
    assert {key: value for key, value in published.items() if key not in timings} == \
        {key: value for key, value in uninterrupted.items() if key not in timings}
