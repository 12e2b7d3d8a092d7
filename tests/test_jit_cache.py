"""Numba's cache follows rjfit's source (rjfit.jit_cache): a change to any source file gives another cache folder,
so no compiled function outlives a change to a function it inlines from another file."""
import os
import subprocess
import sys

from rjfit.jit_cache import KEPT_VERSIONS, prune_versions, source_key, use_source_keyed_cache


def test_the_key_changes_with_any_source_file_and_only_with_one(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "b.py").write_text("y = 2\n")
    (package / "notes.md").write_text("not source\n")
    key = source_key(package)
    assert source_key(package) == key
    (package / "notes.md").write_text("changed, still not source\n")
    assert source_key(package) == key
    (package / "sub" / "b.py").write_text("y = 3\n")       # a callee in another file
    changed = source_key(package)
    assert changed != key
    (package / "sub" / "b.py").rename(package / "b2.py")   # the same text under another name
    assert source_key(package) not in (key, changed)


def test_the_folder_is_keyed_and_a_users_choice_is_kept(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "a.py").write_text("x = 1\n")
    environ = {"XDG_CACHE_HOME": str(tmp_path / "cache")}
    folder = use_source_keyed_cache(package, environ)
    assert folder == environ["NUMBA_CACHE_DIR"] == str(tmp_path / "cache" / "rjfit" / "numba" / source_key(package))
    assert os.path.isdir(folder)
    chosen = {"NUMBA_CACHE_DIR": str(tmp_path / "mine"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    assert use_source_keyed_cache(package, chosen) is None and chosen["NUMBA_CACHE_DIR"] == str(tmp_path / "mine")


def test_importing_rjfit_points_numba_at_the_keyed_folder(tmp_path):
    """In a fresh interpreter: ``import rjfit`` sets the folder before Numba defines any of rjfit's functions, and a
    compiled function's cache files land under it."""
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    code = ("import rjfit, numba, os; from rjfit.sampler.regions.materials.passes.edges import boundary_value; "
            "assert boundary_value(1.0, 3.0, 2.0) == 1.0; "
            "print(os.environ['NUMBA_CACHE_DIR']); print(numba.config.CACHE_DIR)")
    lines = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                           check=True).stdout.split()
    assert lines[0] == lines[1] and lines[0].startswith(str(tmp_path / "cache" / "rjfit" / "numba"))
    written = [name for _, _, names in os.walk(lines[0]) for name in names]
    assert any("boundary_value" in name and name.endswith(".nbi") for name in written), written


def test_a_new_version_removes_the_least_recently_used_beyond_the_kept(tmp_path):
    """Each version's folder is tens of MB: making a new one keeps the most recently used KEPT_VERSIONS and leaves
    anything that is not a version folder."""
    parent = tmp_path / "cache" / "rjfit" / "numba"
    parent.mkdir(parents=True)
    old = [parent / f"{index:016x}" for index in range(KEPT_VERSIONS + 2)]
    for age, path in enumerate(old):
        path.mkdir()
        (path / "f.nbi").write_text("x")
        os.utime(path, (1_000_000 + age, 1_000_000 + age))      # the last made is the most recently used
    (parent / "notes").mkdir()
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "a.py").write_text("x = 1\n")
    folder = use_source_keyed_cache(package, {"XDG_CACHE_HOME": str(tmp_path / "cache")})
    left = sorted(path.name for path in parent.iterdir())
    assert os.path.basename(folder) in left and "notes" in left
    assert left == sorted(["notes", os.path.basename(folder)] + [path.name for path in old[-(KEPT_VERSIONS - 1):]])
    # a use of an existing version prunes nothing
    assert use_source_keyed_cache(package, {"XDG_CACHE_HOME": str(tmp_path / "cache")}) == folder
    assert sorted(path.name for path in parent.iterdir()) == left
    assert prune_versions(parent, keep=1) and sorted(path.name for path in parent.iterdir()) == sorted(
        ["notes", os.path.basename(folder)])
