"""``rtfit cache info|prune`` on a cache built with `PassEntry` directly (no Mitsuba): counts and bytes
per namespace, removal of whole entries oldest first, live claims spared, bad values refused."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.cache_cli import parse_duration, parse_size
from rtfit.experiments.cli import main
from rtfit.reference import cache as cache_mod
from rtfit.reference.cache import PassEntry
from rtfit.reference.estimators import PassResult

DAY = 86400.0


def _render(i: int) -> PassResult:
    mean = np.random.default_rng(i).uniform(0, 1, (50, 3))
    return PassResult(mean, mean * 0.1, 16, i, 0.01)


def _make(root: Path, name: str, passes: int, age_days: float, namespace: str = "", quantity=None) -> Path:
    """An entry of ``passes`` passes whose files were last written ``age_days`` ago."""
    ident = {"what": name, "format": 1, **({"quantity": quantity} if quantity else {})}
    entry = PassEntry(root, ident, namespace=namespace)
    entry.passes(passes, _render)
    t = time.time() - age_days * DAY
    for f in entry.folder.iterdir():
        os.utime(f, (t, t))
    return entry.folder


def _bytes(folder: Path) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(folder) for f in fs)


@pytest.fixture
def cache(tmp_path):
    root = tmp_path / "cache"
    folders = {
        "img-old": _make(root, "img-old", 3, 40, quantity="radiance"),
        "img-new": _make(root, "img-new", 2, 0.01, quantity="radiance"),
        "probes": _make(root, "probes", 4, 20, quantity="irradiance"),
        "occ": _make(root, "occ", 5, 35, namespace="occlusion"),
        "sky": _make(root, "sky", 1, 2, namespace="sky"),
    }
    (root / "sdf-grids").mkdir()
    (root / "sdf-grids" / "g.npz").write_bytes(b"x" * 1000)
    return root, folders


def _run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_duration_and_size_units():
    assert parse_duration("30d") == 30 * 86400
    assert parse_duration("12h") == 43200
    assert parse_duration("1.5w") == 1.5 * 7 * 86400
    assert parse_duration("90m") == 5400 and parse_duration("45s") == 45
    assert parse_size("2G") == 2 * 1024**3
    assert parse_size("500M") == 500 * 1024**2
    assert parse_size("1.5GiB") == int(1.5 * 1024**3)
    assert parse_size("4096") == 4096 and parse_size("0") == 0
    for bad in ("3x", "-1", "", "12", "d", "1e3d"):
        with pytest.raises(ValueError):
            parse_duration(bad)
    for bad in ("-1", "2X", "G", "1.2.3M", ""):
        with pytest.raises(ValueError):
            parse_size(bad)


def test_info_counts_entries_passes_and_bytes_by_namespace(cache, capsys):
    root, folders = cache
    code, out, _ = _run(capsys, "cache", "info", "--cache", str(root))
    assert code == 0
    lines = out.splitlines()
    total = sum(_bytes(f) for f in folders.values())
    assert lines[0].startswith(f"rtfit cache {root}: 5 entries, 15 passes, ")
    rows = {
        ln.split()[0]: ln.split()
        for ln in lines[2:]
        if ln.split() and ln.split()[0] in {"images", "probes", "occlusion", "sky"}
    }
    assert [rows[n][1:3] for n in ("images", "probes", "occlusion", "sky")] == [
        ["2", "5"],
        ["1", "4"],
        ["1", "5"],
        ["1", "1"],
    ]
    # Sizes as printed (KiB, one decimal) agree with the bytes on disk.
    kib = {n: float(rows[n][3]) for n in rows if rows[n][4] == "KiB"}
    assert kib["occlusion"] == pytest.approx(_bytes(folders["occ"]) / 1024, abs=0.051)
    img = _bytes(folders["img-old"]) + _bytes(folders["img-new"])
    assert kib["images"] == pytest.approx(img / 1024, abs=0.051)
    assert f"{total / 1024:.1f} KiB" in lines[0]
    assert any(ln.startswith("sdf-grids/: 1 files, 1000 B") for ln in lines)
    # Oldest and newest use: the ages planted above (40 days ago … 15 minutes ago).
    oldest = time.strftime("%Y-%m-%d", time.gmtime(time.time() - 40 * DAY))
    assert f"last used {oldest}" in lines[0]


def test_info_of_an_empty_or_missing_cache(tmp_path, capsys):
    code, out, _ = _run(capsys, "cache", "info", "--cache", str(tmp_path / "none"))
    assert code == 0 and "no entries" in out
    assert not (tmp_path / "none").exists()


def test_prune_older_than_removes_whole_old_entries(cache, capsys):
    root, f = cache
    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--older-than", "30d", "--dry-run")
    assert code == 0
    assert sum(ln.startswith("would remove ") for ln in out.splitlines()) == 2
    assert all(p.is_dir() for p in f.values())  # a dry run removes nothing

    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--older-than", "30d")
    assert code == 0
    removed = [ln for ln in out.splitlines() if ln.startswith("removed ")]
    assert len(removed) == 2
    assert removed[0].startswith(f"removed {f['img-old'].relative_to(root).as_posix()[:15]}")  # oldest first
    assert not f["img-old"].exists() and not f["occ"].exists()
    assert f["img-new"].is_dir() and f["probes"].is_dir() and f["sky"].is_dir()
    assert (root / "sdf-grids" / "g.npz").is_file()  # not an entry: left alone
    assert not list(root.rglob(".*removing*"))
    # The survivors are intact: every pass still loads.
    assert PassEntry(root, {"what": "probes", "format": 1, "quantity": "irradiance"}).load(3) is not None


def test_prune_max_size_removes_oldest_until_the_rest_fits(cache, capsys):
    root, f = cache
    by_age = ["img-old", "occ", "probes", "sky", "img-new"]  # oldest last use first
    keep = _bytes(f["sky"]) + _bytes(f["img-new"])
    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--max-size", str(keep))
    assert code == 0
    assert [name for name in by_age if not f[name].exists()] == ["img-old", "occ", "probes"]
    left = sum(_bytes(f[n]) for n in ("sky", "img-new"))
    assert left <= keep
    assert out.splitlines()[-1].endswith(f"{left / 1024:.1f} KiB left")


def test_an_entry_with_a_live_claim_is_never_removed(cache, capsys):
    root, f = cache
    live = f["img-old"] / "pass-00007.claim"  # this process, alive, rendering pass 7
    live.write_text(json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}))
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = f["occ"] / "pass-00009.claim"  # a process of this host that is gone
    stale.write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead.stdout), "started": 0}))
    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--older-than", "30d")
    assert code == 0
    assert f["img-old"].is_dir() and live.is_file()
    assert any(ln.startswith("kept ") and "in use by a running process" in ln for ln in out.splitlines())
    assert not f["occ"].exists()
    # Also under --max-size 0 (everything must go): the claimed entry stays, all others go.
    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--max-size", "0")
    assert code == 0
    assert [n for n, p in f.items() if p.exists()] == ["img-old"]


def test_an_interrupted_removal_leaves_no_half_entry(cache, capsys, monkeypatch):
    root, f = cache
    real = cache_mod.Path.unlink
    calls = []

    def dies_after_one(self, *a, **k):
        calls.append(self)
        if len(calls) > 1:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(cache_mod.Path, "unlink", dies_after_one)
    assert main(["cache", "prune", "--cache", str(root), "--older-than", "39d"]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    # The entry left the cache's layout whole (renamed first), so no reader sees half of it …
    assert not f["img-old"].exists()
    code, out, _ = _run(capsys, "cache", "info", "--cache", str(root))
    assert out.splitlines()[0].startswith(f"rtfit cache {root}: 4 entries, 12 passes")
    # … and the next prune deletes what is left of it.
    code, out, _ = _run(capsys, "cache", "prune", "--cache", str(root), "--older-than", "1000d")
    assert code == 0 and "left half-removed by an interrupted prune" in out
    assert not list(root.rglob(".*removing*"))


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--older-than", "3x"], "'3x'"),
        (["--max-size", "-1"], "'-1'"),
        (["--max-size", "2X"], "'2X'"),
        (["--older-than", "12"], "'12'"),
        ([], "--older-than"),
    ],
)
def test_bad_values_are_one_line_and_remove_nothing(cache, capsys, argv, needle):
    root, f = cache
    code, out, err = _run(capsys, "cache", "prune", "--cache", str(root), *argv)
    assert code == 2 and out == ""
    line = err.strip()
    assert line.startswith("rtfit: error: ") and "\n" not in line and needle in line, line
    assert all(p.is_dir() for p in f.values())
