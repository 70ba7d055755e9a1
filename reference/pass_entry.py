"""The pass store every reference in rtfit uses: `PassEntry` (independent Monte Carlo passes, resumable,
shared between processes by claims) and `ComputedEntry` (one deterministic computation's arrays).

An entry lives in ``ROOT/[NAMESPACE/]<key[:2]>/<key>/``; its key is `entry_key` of an identity dict that
names everything its numbers depend on (`array_digest` for probe arrays in it). Each missing pass is
claimed by one process (an ``O_EXCL`` claim file kept fresh by a heartbeat thread; a claim of a dead
process is taken over), rendered under the per-pass watchdog, checked finite and written atomically;
`PASS_COUNTS` counts what this process requested and rendered. `pass_size` and `pool_passes` are the
sizes of a request's passes and their exact pooling. `rtfit.reference.cache` builds the radiance and
irradiance reference cache on it and re-exports these names; `rtfit.reference.cache_prune` inspects and
prunes the entries on disk.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import socket
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .budget import PassBudgetExceeded, PassWatchdog, check_finite
from .estimators import PassResult
from .io import atomic_write_bytes, atomic_write_json, read_exr, rgb_group, write_exr
from .processes import process_alive, process_start
from .progress import progress_bar

log = logging.getLogger("rtfit.reference")


def pass_size(spp: int, pass_spp: int, index: int) -> int:
    """Samples of pass ``index`` of a request for ``spp`` in passes of ``pass_spp``: ``pass_spp``, the last
    pass the remainder, at least 2 (the variance needs two: a remainder of 1 renders one sample more). A
    ``pass_spp`` above ``spp`` gives one pass of ``spp``."""
    return max(min(int(pass_spp), int(spp) - int(index) * int(pass_spp)), 2)


def pool_passes(passes: list[PassResult]) -> tuple[np.ndarray, np.ndarray, int]:
    """Exact pooling of independent passes → (mean, standard error of the mean, total samples)."""
    n_i = np.array([p.spp for p in passes], dtype=np.float64)
    total = float(n_i.sum())
    mean = sum(p.spp * p.mean for p in passes) / total
    within = sum((p.spp - 1) * p.var for p in passes)
    between = sum(p.spp * (p.mean - mean) ** 2 for p in passes)
    var = (within + between) / (total - 1)
    return mean, np.sqrt(var / total), int(total)


def entry_key(ident: dict) -> str:
    """SHA-256 of the canonical JSON of ``ident`` (sorted keys): the key of a cache entry."""
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()


def array_digest(*arrays) -> str:
    """SHA-256 over the float32 bytes of ``arrays`` (probe points, normals): part of an entry's identity."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=np.float32).tobytes())
    return h.hexdigest()


class PassEntry:
    """One cache entry of independent Monte Carlo passes: ``ROOT/[NAMESPACE/]<key[:2]>/<key>/``.

    Every reference in rtfit (radiance images, irradiance probes, ray-cast occlusion, the atmosphere's
    sky renders) is stored this way: ``pass-NNNNN.<exr|npz>`` holds a pass's per-element mean and
    unbiased sample variance (float32 in EXR, float64 in npz), ``pass-NNNNN.json`` its seed, spp and
    timing (a pass counts only once both exist), ``entry.json`` what the entry is. Files are written
    atomically; an unreadable or truncated pass is re-rendered, never trusted. `passes` loads what is
    there and renders the rest.

    ``storage="exr"`` keeps passes viewable in an image tool (arrays of shape (H, W, 3), or (N, 3) stored
    as a (1, N, 3) image); ``"npz"`` stores arrays of any shape.
    """

    def __init__(
        self, root, ident: dict, *, namespace: str = "", storage: str = "npz", info: dict | None = None
    ):
        if storage not in ("exr", "npz"):
            raise ValueError(f"storage must be 'exr' or 'npz' (got {storage!r})")
        if storage == "npz":  # passes written as float64 (earlier npz entries held float32: other keys)
            ident = {**ident, "pass_store": "npz-float64"}
        self.key = entry_key(ident)
        base = Path(root) / namespace if namespace else Path(root)
        self.folder = base / self.key[:2] / self.key
        self.storage = storage
        self.info = {"key": self.key, **ident, **(info or {})}
        self._said: set[tuple[str, str]] = set()  # (pass file, why) already logged: `passes` loads thrice

    def _say(self, level: int, data: Path, why: str, text: str, *args) -> None:
        """Log ``text`` once per pass file and reason: `passes` looks at a missing pass up to three times
        (before, while and after claiming it), and a bad pass is one line, not three (issue 32)."""
        if (str(data), why) not in self._said:
            self._said.add((str(data), why))
            log.log(level, text, data, *args)

    def _files(self, index: int) -> tuple[Path, Path]:
        return self.folder / f"pass-{index:05d}.{self.storage}", self.folder / f"pass-{index:05d}.json"

    def load(
        self, index: int, shape: tuple[int, ...] | None = None, spp: int | None = None
    ) -> PassResult | None:
        """Pass ``index`` as stored (float32 values in float64 arrays), or None if absent or unreadable, or
        (``spp`` given) if it holds another number of samples: the entry's key covers the pass size, not
        the total, so a short last pass of an earlier, smaller request (or an edited ``spp``) is rendered
        again at this request's size rather than pooled short (issue 32)."""
        data, meta = self._files(index)
        if not (data.exists() and meta.exists()):
            return None
        try:
            info = json.loads(meta.read_text())
            if self.storage == "exr":
                ch = read_exr(data)
                mean, var = rgb_group(ch, "mean"), rgb_group(ch, "var")
            else:
                with open(data, "rb") as fh:
                    if fh.read(4) != b"PK\x03\x04":  # np.load reads anything else as a pickle, and says so
                        raise ValueError("not an npz (zip) archive")
                with open(data, "rb") as fh, np.load(fh) as z:  # own handle: closed even if np.load fails
                    mean, var = z["mean"], z["var"]
            mean, var = mean.astype(np.float64), var.astype(np.float64)
            if shape is not None:
                mean, var = mean.reshape(shape), var.reshape(shape)
            n = int(info["spp"])
            if n < 1:
                raise ValueError(f"spp {n}")
            if spp is not None and n != spp:
                self._say(
                    logging.INFO,
                    data,
                    f"spp {n}",
                    "cached pass %s holds %d samples, this request needs %d: it is rendered again",
                    n,
                    spp,
                )
                return None
            return PassResult(mean, var, n, int(info["seed"]), float(info["seconds"]))
        except (OSError, ValueError, RuntimeError, KeyError, EOFError, TypeError, zipfile.BadZipFile) as e:
            # unreadable leftovers are re-rendered, never trusted; one line says which (issue 32)
            why = " ".join(f"{type(e).__name__}: {e}".split())
            why = why if len(why) <= 160 else why[:159] + "…"
            self._say(
                logging.WARNING, data, why, "cached pass %s is unreadable (%s): it is rendered again", why
            )
            return None

    def save(self, index: int, result: PassResult) -> PassResult:
        """Write pass ``index`` atomically; returns it with the values exactly as stored, so that a fresh
        result and one resumed from the cache are identical. EXR passes are float32 (what image tools
        read); npz passes keep the float64 moments as computed (an ill-conditioned fit downstream, such
        as sdf-occlusion's sunsky Evans fit, moves by percents under float32 rounding of its target)."""
        data, meta = self._files(index)
        self.folder.mkdir(parents=True, exist_ok=True)
        dtype = np.float32 if self.storage == "exr" else np.float64
        mean, var = result.mean.astype(dtype), result.var.astype(dtype)
        if self.storage == "exr":
            img = (1, -1, 3) if mean.ndim == 2 else mean.shape
            write_exr(data, {"mean": mean.reshape(img), "var": var.reshape(img)})
        else:
            buf = io.BytesIO()
            np.savez(buf, mean=mean, var=var)
            atomic_write_bytes(data, buf.getvalue())
        atomic_write_json(
            meta, {"index": index, "spp": result.spp, "seed": result.seed, "seconds": result.seconds}
        )
        return PassResult(
            mean.astype(np.float64), var.astype(np.float64), result.spp, result.seed, result.seconds
        )

    def _write_info(self) -> None:
        """Write entry.json (every process that finds passes missing does, unclaimed: the bytes are the same
        from every writer), then remove every other writer's temporary of it. Such a temporary is the
        leftover of a writer killed mid-write (a Ray worker killed while its point set up left one behind),
        or belongs to a writer about to rename it, which then finds it gone and stops (below): entry.json
        already holds its bytes."""
        final = self.folder / "entry.json"
        try:
            atomic_write_json(final, self.info)
        except FileNotFoundError:  # another writer removed our temporary after writing the same bytes
            if not final.is_file():
                raise
        for leftover in self.folder.glob(".entry.json.*.tmp"):
            leftover.unlink(missing_ok=True)

    # -- claims: one process renders a pass, the others wait for it
    def _claim_file(self, index: int) -> Path:
        return self.folder / f"pass-{index:05d}.claim"

    def claim(self, index: int) -> bool:
        """Try to become the one process rendering pass ``index`` (an ``O_EXCL`` claim file holding the
        host, pid and start time). A claim left by a dead process of this host, or one whose owner
        stopped refreshing it for `CLAIM_STALE_SECONDS`, is taken over."""
        path = self._claim_file(index)
        for _ in range(2):  # second try after removing a stale claim
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                if not self.claim_is_stale(path):
                    return False
                path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as f:
                json.dump(
                    {
                        "host": socket.gethostname(),
                        "pid": os.getpid(),
                        "start": process_start(os.getpid()),
                        "started": time.time(),
                    },
                    f,
                )
            # Holding the claim, no other process writes this pass: temporary files of it are leftovers
            # of a writer that was killed mid-write (atomic writes rename a `.NAME.<hex>.tmp` file).
            for leftover in self.folder.glob(f".pass-{index:05d}.*.tmp"):
                leftover.unlink(missing_ok=True)
            return True
        return False

    def release(self, index: int) -> None:
        self._claim_file(index).unlink(missing_ok=True)

    @staticmethod
    def claim_is_stale(path: Path) -> bool:
        """True when the claim file ``path`` holds no live claim: gone meanwhile, torn (its writer died
        between open and write), left by a dead process of this host, or not refreshed for
        `CLAIM_STALE_SECONDS` (`rtfit.reference.cache_prune` spares entries with a live claim)."""
        try:
            age = time.time() - path.stat().st_mtime
        except OSError:
            return True  # released meanwhile: try again
        try:
            info = json.loads(path.read_text())
        except FileNotFoundError:
            return True  # released meanwhile: try again
        except (OSError, ValueError):
            # Empty or torn: its writer died between open and write, or is between them now (a live claim:
            # taken over, its pass was rendered twice — CI under load, session 29). Only an old one is dead.
            return age > TORN_CLAIM_SECONDS
        pid, start = int(info.get("pid", -1)), info.get("start")
        if info.get("host") == socket.gethostname() and not process_alive(pid, start):
            return True
        return age > CLAIM_STALE_SECONDS

    def passes(
        self,
        count: int,
        render: Callable[[int], PassResult],
        *,
        shape: tuple[int, ...] | None = None,
        progress: bool = False,
        label: str | None = None,
        before_render: Callable[[], None] | None = None,
        spp_of: Callable[[int], int] | None = None,
    ) -> tuple[list[PassResult], int]:
        """The first ``count`` passes: loaded where cached, else ``render(i)`` and saved. Returns the passes
        and how many were rendered by this call. ``before_render`` runs once, only if something is
        missing (load the Mitsuba scene there, not before). ``spp_of(i)``: the samples pass i must hold
        (`pass_size`); a cached pass of another size is rendered again (`load`).

        Several processes may share one cache: each missing pass is claimed (`claim`) by exactly one of
        them; the others render the passes nobody holds, then wait for the claimed ones to appear
        (polling; a claim whose owner died is taken over). While rendering, the claim's mtime is
        refreshed by a heartbeat thread, so that a claim is stale only when its owner is gone."""
        size = spp_of or (lambda _i: None)
        results = [self.load(i, shape, size(i)) for i in range(count)]
        missing = [i for i, r in enumerate(results) if r is None]
        name = label or f"reference {self.key[:8]}"
        # A pass this process rendered earlier (two cases sharing a reference) is not resumed from the cache.
        ours = sum(1 for i, r in enumerate(results) if r is not None and PASS_COUNTS.made(self._files(i)[0]))
        if not missing:
            PASS_COUNTS.add(count, ours)
            return [r for r in results if r is not None], 0
        if count - len(missing) - ours:
            log.info("%s: resumed %d of %d passes from the cache", name, count - len(missing) - ours, count)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._write_info()
        prepared = False
        rendered = 0
        bar = progress_bar(len(missing), name, progress, unit="pass")
        waits = 0
        while missing:
            held_elsewhere = []
            for i in missing:
                cached = self.load(i, shape, size(i))  # another process may have finished it meanwhile
                if cached is None and self.claim(i):
                    try:
                        # Look again now that we hold the claim: the owner before us saves a pass before
                        # it releases it, so a pass finished between our load and our claim is seen here.
                        cached = self.load(i, shape, size(i))
                        if cached is None:
                            if not prepared and before_render is not None:
                                before_render()
                            prepared = True
                            what = f"{name} pass {i + 1} of {count}"
                            with _Heartbeat(self._claim_file(i)), PassWatchdog(what):
                                try:
                                    result = render(i)
                                except PassBudgetExceeded as e:  # one line naming the case and pass
                                    raise PassBudgetExceeded(f"{what}: {e}") from None
                                cached = self.save(i, check_finite(result, what))
                            rendered += 1
                            PASS_COUNTS.mark(self._files(i)[0])
                    finally:
                        self.release(i)
                if cached is None:
                    held_elsewhere.append(i)
                else:
                    results[i] = cached
                    bar.update(1)
            missing = held_elsewhere
            if missing:
                waits += 1
                if waits == 1:
                    log.info(
                        "%s: %d passes are being rendered by another process; waiting", name, len(missing)
                    )
                time.sleep(CLAIM_POLL_SECONDS)
        bar.close()
        PASS_COUNTS.add(count, rendered + ours)
        return [r for r in results if r is not None], rendered


class PassCounts:
    """Passes requested from `PassEntry.passes` in this process, and how many of them it rendered (the
    rest came from the cache); thread-safe. A pass this process rendered and then reads again from the
    cache (two cases or experiments sharing a reference) counts as rendered: "resumed" names only passes
    that existed before the process started (`mark`, `made`). The runner reads `PASS_COUNTS` before and
    after an experiment to say how much of it was resumed. Passes of jobs run in other processes (the
    process and Ray executors) are counted there, not here."""

    def __init__(self):
        self._lock = threading.Lock()
        self.requested = 0
        self.rendered = 0
        self._made: set[str] = set()

    def add(self, requested: int, rendered: int) -> None:
        with self._lock:
            self.requested += int(requested)
            self.rendered += int(rendered)

    def mark(self, path: Path) -> None:
        """Record the pass file ``path`` as rendered by this process."""
        with self._lock:
            self._made.add(str(path))

    def made(self, path: Path) -> bool:
        """True when this process rendered the pass file ``path`` (`mark`)."""
        with self._lock:
            return str(path) in self._made

    def snapshot(self) -> tuple[int, int]:
        """(requested, rendered) so far."""
        with self._lock:
            return self.requested, self.rendered


PASS_COUNTS = PassCounts()


TORN_CLAIM_SECONDS = 10.0
"""A claim file that does not parse is taken for its writer's last act once it is this old (its writer
creates it and writes its few bytes at once: a live one is seconds old at most, even on a loaded machine;
as `rtfit.experiments.atomic.TORN_OWNER_SECONDS` for a result directory's owner file)."""

CLAIM_STALE_SECONDS = 600.0
"""A claim not refreshed for this long belongs to a process that is gone (heartbeats come every 10 s; a
claim of a dead process on this host is taken over at once, this bound is for other hosts sharing the cache
and for a heartbeat starved by a long kernel that holds the GIL)."""
CLAIM_POLL_SECONDS = 0.5
"""How often a process waiting for another's pass looks for it."""
_HEARTBEAT_SECONDS = 10.0


class _Heartbeat:
    """Touch a claim file every few seconds while the pass it guards renders (a daemon thread)."""

    def __init__(self, path: Path):
        self.path = path
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.wait(_HEARTBEAT_SECONDS):
            try:
                os.utime(self.path)
            except OSError:
                return

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        return False


class ComputedEntry:
    """One deterministic computation's arrays (a float64 quadrature that takes minutes), stored once:
    ``ROOT/NAMESPACE/<key[:2]>/<key>/result.npz`` beside ``entry.json``, the same folder layout as a
    `PassEntry` (so ``rtfit cache info``/``prune`` see it as an entry of one complete item).

    The key is `entry_key` of ``ident``, which must name everything the numbers depend on, including
    a format version the computing code bumps when its arithmetic changes. `get` loads the arrays, or
    computes, writes (atomically) and returns them; an unreadable or truncated file is recomputed, never
    trusted. Two processes computing the same entry write identical bytes, so no claim is needed: the
    cost of a rare duplicate is one computation."""

    RESULT = "result.npz"

    def __init__(self, root, ident: dict, *, namespace: str, info: dict | None = None):
        self.key = entry_key(ident)
        self.folder = Path(root) / namespace / self.key[:2] / self.key
        self.info = {"key": self.key, **ident, **(info or {})}

    def load(self) -> dict[str, np.ndarray] | None:
        """The stored arrays (float64 as computed), or None if absent or unreadable."""
        path = self.folder / self.RESULT
        if not path.is_file():
            return None
        try:
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            return None  # a truncated or corrupt file is recomputed

    def get(self, compute: Callable[[], dict[str, np.ndarray]]) -> tuple[dict[str, np.ndarray], bool]:
        """``(arrays, computed)``: the stored arrays, or ``compute()``'s, written first. Values that are
        None are not stored (absent on load)."""
        found = self.load()
        if found is not None:
            return found, False
        arrays = {k: np.asarray(v) for k, v in compute().items() if v is not None}
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.folder / "entry.json", self.info)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(self.folder / self.RESULT, buf.getvalue())
        return arrays, True
