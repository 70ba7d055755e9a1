"""The installed package carries every data file the code reads (issue 33's GPU run: a non-editable install
lacked scenes/library/volumes/*.vol, so the clouds and aerial-perspective experiments could not load their
scenes there while every test here, run from the source tree, passed).

Checked from pyproject.toml alone, the way setuptools reads it: each non-Python file under a package folder
must belong to a listed package and match one of that package's package-data patterns."""

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _package_folders(conf: dict) -> dict[str, Path]:
    """Dotted package name → source folder, through [tool.setuptools.package-dir]."""
    roots = conf["package-dir"]
    folders = {}
    for name in conf["packages"]:
        parent = max((r for r in roots if name == r or name.startswith(r + ".")), key=len)
        rest = name[len(parent) :].lstrip(".")
        folders[name] = ROOT / roots[parent] / Path(*rest.split(".")) if rest else ROOT / roots[parent]
    return folders


def _data_files(folder: Path):
    for path in sorted(folder.rglob("*")):
        if path.is_file() and path.suffix not in {".py", ".pyc"} and "__pycache__" not in path.parts:
            yield path


def test_every_data_file_is_shipped():
    conf = _setuptools()
    folders = _package_folders(conf)
    by_folder = {folder: name for name, folder in folders.items()}
    patterns = conf.get("package-data", {})
    missing = []
    for folder in folders.values():
        for path in _data_files(folder):
            owner = by_folder.get(path.parent)
            globs = patterns.get(owner, []) if owner else []
            if not any(fnmatch.fnmatch(path.name, g) for g in globs):
                where = owner or "none: its folder is not listed"
                missing.append(f"{path.relative_to(ROOT)} (package {where})")
    assert not missing, "not shipped by pyproject.toml: " + ", ".join(sorted(set(missing)))


def test_the_check_sees_a_file_left_out(tmp_path):
    """The test above is not vacuous: a planted file of an unlisted kind is found."""
    conf = _setuptools()
    folders = _package_folders(conf)
    assert folders["rtfit.scenes.library"] == ROOT / "scenes" / "library"
    patterns = conf["package-data"]["rtfit.scenes.library"]
    assert not any(fnmatch.fnmatch("fog.vdb", g) for g in patterns)
