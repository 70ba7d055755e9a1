"""Content-addressed, resumable cache of Monte Carlo references.

An entry is identified by a SHA-256 key over everything that determines its samples: the scene's
physics hash (`rtfit.scenes.scene_hash`, which hashes referenced files by content), the quantity
(radiance image or irradiance probes, with the probe points), the integrator chosen by the rule,
the variant, the base seed, the samples per pass, the Mitsuba and Dr.Jit versions and the format
version of this module. The requested total ``spp`` is *not* part of the key: an entry holds
independent passes, pass *i* seeded with ``sub_seed(seed, "pass", i)``, and a request for N samples
uses exactly its first ceil(N / pass_spp) passes, rendering only those not cached yet. So a result
never depends on the cache's history, an interrupted run loses at most the pass in flight, and
asking for more samples later adds passes to the same entry.

Layout: ``ROOT/<key[:2]>/<key>/`` with ``pass-NNNNN.exr`` (per-element mean and unbiased sample
variance, float32 channels ``mean.*`` and ``var.*``), ``pass-NNNNN.json`` (its seed, spp and
timing; a pass counts only once both files exist), ``entry.json`` (what the entry is, for humans
and tools) and ``reference.exr`` (the latest combination: ``R,G,B`` mean and ``stderr.*``). Every
file is written atomically, so two workers finishing the same pass overwrite it with identical
content and never leave half a file.

Combination of passes (sizes n_i, means m_i, variances s_i², N = Σ n_i) is exact pooling:
mean M = Σ n_i m_i / N, variance S² = [Σ (n_i − 1) s_i² + Σ n_i (m_i − M)²] / (N − 1), and the
standard error of M is sqrt(S² / N), computed in float64.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import os
import socket
import threading
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.scenes import Scene, scene_hash, scene_to_dict

from . import fog_integrator
from .budget import PassBudgetExceeded, PassWatchdog, check_finite
from .build import load_mitsuba_scene
from .estimators import PassResult, device_probes, irradiance_pass, launch_identity, radiance_pass, sub_seed
from .height_fog import ESTIMATOR as FOG_ESTIMATOR
from .integrators import choose_integrator
from .io import atomic_write_bytes, atomic_write_json, read_exr, rgb_group, write_exr
from .mitsuba_xml import xml_dependencies
from .progress import progress_bar
from .variants import callers_variant

log = logging.getLogger("rtfit.reference")

CACHE_FORMAT = 1
DEFAULT_PASS_SPP = 256
# Relative resolution of a reference value, whatever its sample count: Mitsuba's and rtfit's
# per-sample weights are float32. Empirical: the largest deviation from a closed form seen with a
# statistical error far below it was 3.6e-6 relative (0.27° sun + constant sky, irradiance probes,
# statistical error 6e-8); 1e-5 leaves margin. Used by `Reference.sigma`.
RELATIVE_PRECISION_FLOOR = 1e-5
QUANTITIES = ("radiance", "irradiance")
REFERENCE_PASS_DTYPE = np.float32
"""The precision `ReferenceCache` stores its radiance and irradiance passes in (EXR, float32), and so the
precision those passes round their float64 mean and variance to on the device before the copy to the host
(``radiance_pass(..., dtype=)``): the values stored are bit-identical to rounding on the host (both round to
nearest even), with half the bytes copied from a GPU. Benchmarks time reference passes with it."""


def default_cache_dir() -> Path:
    """``$RTFIT_CACHE`` if set, else ``$XDG_CACHE_HOME/rtfit`` (``~/.cache/rtfit``)."""
    env = os.environ.get("RTFIT_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rtfit"


@dataclass(frozen=True)
class ReferenceRequest:
    """What to estimate. Plain data only (safe to send to another process or machine).

    ``quantity="radiance"``: point-sampled radiance at every pixel centre of the scene's camera.
    ``quantity="irradiance"``: irradiance at ``points`` (N, 3) with unit ``normals`` (N, 3), with
    ``transport`` "direct" (MIS emitter + cosine sampling) or "global" (path-traced).
    """

    scene: Scene
    spp: int
    quantity: str = "radiance"
    seed: int = 0
    variant: str = "llvm_ad_rgb"
    pass_spp: int = DEFAULT_PASS_SPP
    points: np.ndarray | None = field(default=None, compare=False)
    normals: np.ndarray | None = field(default=None, compare=False)
    transport: str = "direct"

    def __post_init__(self):
        if self.quantity not in QUANTITIES:
            raise ValueError(f"quantity must be one of {QUANTITIES} (got {self.quantity!r})")
        if not isinstance(self.spp, int) or self.spp < 2:
            raise ValueError(f"spp must be an integer >= 2 (got {self.spp!r})")
        if not isinstance(self.pass_spp, int) or self.pass_spp < 2:
            raise ValueError(f"pass_spp must be an integer >= 2 (got {self.pass_spp!r})")
        if self.quantity == "irradiance":
            if self.points is None or self.normals is None:
                raise ValueError("an irradiance request needs points and normals")
            p = np.asarray(self.points, dtype=np.float64)
            n = np.asarray(self.normals, dtype=np.float64)
            if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape:
                raise ValueError(f"points and normals must both be (N, 3) (got {p.shape} and {n.shape})")
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
                raise ValueError("points and normals must be finite")
            norms = np.linalg.norm(n, axis=1)
            if np.any(np.abs(norms - 1.0) > 1e-3):
                raise ValueError("normals must be unit length (normalise them first)")

    @property
    def passes(self) -> int:
        return -(-self.spp // self.pass_spp)

    def integrator(self) -> dict:
        if self.quantity == "radiance":
            return choose_integrator(self.scene).to_dict()
        return {
            "type": f"irradiance-probe-{self.transport}",
            "max_depth": None,
            "reason": "Mitsuba emitter sampling + cosine sampling (MIS)"
            if self.transport == "direct"
            else "path-traced radiance along cosine-sampled directions",
        }

    def key(self) -> str:
        """The cache key: `entry_key` of `identity`."""
        return entry_key(self.identity())

    def identity(self) -> dict:
        """Everything that determines this request's samples (see the module docstring)."""
        import mitsuba  # mitsuba: loaded only where a reference is made (its version is in the key)

        ident = {
            "format": CACHE_FORMAT,
            "scene": scene_hash(self.scene),
            "quantity": self.quantity,
            "integrator": self.integrator(),
            "variant": self.variant,
            "seed": self.seed,
            "pass_spp": self.pass_spp,
            "versions": {"mitsuba": mitsuba.__version__, "drjit": dr.__version__},
            **launch_identity(self.variant),
        }
        if any(m.kind == "exponential_fog" for m in self.scene.media):  # the estimator made the samples
            fog_path = fog_integrator.applies(self.scene, choose_integrator(self.scene).mitsuba_dict())
            ident["medium_estimator"] = fog_integrator.ESTIMATOR if fog_path else FOG_ESTIMATOR
        xml = [sh.file for sh in self.scene.shapes if sh.kind == "mitsuba_xml"]
        if xml:  # every file Mitsuba's parser loads for them (includes, <path> meshes), not only the XML
            ident["xml_files"] = [xml_dependencies(f, variant=self.variant).digest for f in xml]
        if self.quantity == "irradiance":
            ident["probes"] = array_digest(self.points, self.normals)
            ident["transport"] = self.transport
        return ident


@dataclass(frozen=True)
class Reference:
    """A combined Monte Carlo reference: ``mean`` and its per-element standard error ``stderr``.

    Arrays are float64, (H, W, 3) for radiance images and (N, 3) for irradiance probes.
    """

    key: str
    path: str
    quantity: str
    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    passes_rendered: int  # how many of ``passes`` this call rendered (the rest came from the cache)
    integrator: dict
    variant: str
    render_seconds: float  # summed over all passes used, whenever they were rendered

    def sigma(self) -> np.ndarray:
        """Uncertainty to compare against: the standard error combined with the float32 precision
        floor, sqrt(stderr² + (RELATIVE_PRECISION_FLOOR·|mean|)²). Use it for z-scores and noise floors."""
        return np.sqrt(self.stderr**2 + (RELATIVE_PRECISION_FLOOR * self.mean) ** 2)

    @property
    def samples_per_second(self) -> float:
        n = self.mean.shape[0] * (self.mean.shape[1] if self.mean.ndim == 3 else 1)
        return n * self.spp / self.render_seconds if self.render_seconds > 0 else math.nan

    def to_dict(self) -> dict:
        """Metadata for results files (no arrays)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = self.stderr / np.abs(self.mean)
        rel = rel[np.isfinite(rel) & (np.abs(self.mean) > 0)]
        return {
            "cache_key": self.key,
            "quantity": self.quantity,
            "integrator": self.integrator.get("type"),
            "max_depth": self.integrator.get("max_depth"),
            "integrator_reason": self.integrator.get("reason"),
            "variant": self.variant,
            "spp": self.spp,
            "passes": self.passes,
            "mean_rel_stderr": float(np.mean(rel)) if rel.size else 0.0,
            "samples_per_second": float(self.samples_per_second) if self.render_seconds > 0 else None,
        }


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
                if not self._claim_is_stale(path):
                    return False
                path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as f:
                json.dump({"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}, f)
            # Holding the claim, no other process writes this pass: temporary files of it are leftovers
            # of a writer that was killed mid-write (atomic writes rename a `.NAME.<hex>.tmp` file).
            for leftover in self.folder.glob(f".pass-{index:05d}.*.tmp"):
                leftover.unlink(missing_ok=True)
            return True
        return False

    def release(self, index: int) -> None:
        self._claim_file(index).unlink(missing_ok=True)

    @staticmethod
    def _claim_is_stale(path: Path) -> bool:
        try:
            info = json.loads(path.read_text())
            age = time.time() - path.stat().st_mtime
        except FileNotFoundError:
            return True  # released meanwhile: try again
        except (OSError, ValueError):
            return True  # a torn claim (its writer died between open and write)
        if info.get("host") == socket.gethostname() and not _pid_alive(int(info.get("pid", -1))):
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


CLAIM_STALE_SECONDS = 600.0
"""A claim not refreshed for this long belongs to a process that is gone (heartbeats come every 10 s; a
claim of a dead process on this host is taken over at once, this bound is for other hosts sharing the cache
and for a heartbeat starved by a long kernel that holds the GIL)."""
CLAIM_POLL_SECONDS = 0.5
"""How often a process waiting for another's pass looks for it."""
_HEARTBEAT_SECONDS = 10.0


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    return True


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


class ReferenceCache:
    """The cache rooted at ``root`` (created on first write)."""

    def __init__(self, root=None):
        self.root = Path(root) if root is not None else default_cache_dir()

    def entry_dir(self, key: str) -> Path:
        return self.root / key[:2] / key

    def get(
        self, request: ReferenceRequest, *, progress: bool = False, label: str | None = None
    ) -> Reference:
        """Return the reference for ``request``, rendering only the passes not cached yet."""
        entry = PassEntry(self.root, request.identity(), storage="exr", info=self._entry_info(request))
        key = entry.key
        as_points = request.quantity == "irradiance"
        loaded: dict = {}

        def load_scene():
            loaded["mi"], loaded["scene"] = load_mitsuba_scene(request.scene, request.variant)
            if as_points:  # on the device once for all the passes rendered
                loaded["probes"] = device_probes(
                    loaded["mi"], request.points, request.normals, normalise=False
                )

        def render(i: int) -> PassResult:
            pass_spp = pass_size(request.spp, request.pass_spp, i)
            seed = sub_seed(request.seed, "pass", i)
            mi, mi_scene = loaded["mi"], loaded["scene"]
            if as_points:
                return irradiance_pass(
                    mi,
                    mi_scene,
                    loaded["probes"],
                    None,
                    pass_spp,
                    seed,
                    request.transport,
                    REFERENCE_PASS_DTYPE,
                )
            return radiance_pass(mi, mi_scene, pass_spp, seed, REFERENCE_PASS_DTYPE)

        with callers_variant():  # rendering activates request.variant; the caller's comes back
            passes, rendered = entry.passes(
                request.passes,
                render,
                shape=(-1, 3) if as_points else None,
                progress=progress,
                label=label or f"reference {key[:8]}",
                before_render=load_scene,
                spp_of=lambda i: pass_size(request.spp, request.pass_spp, i),
            )
        mean, stderr, total = pool_passes(passes)
        if rendered:
            shape = (1, -1, 3) if as_points else mean.shape
            write_exr(
                entry.folder / "reference.exr", {"RGB": mean.reshape(shape), "stderr": stderr.reshape(shape)}
            )
        return Reference(
            key=key,
            path=str(entry.folder),
            quantity=request.quantity,
            mean=mean,
            stderr=stderr,
            spp=total,
            passes=len(passes),
            passes_rendered=rendered,
            integrator=request.integrator(),
            variant=request.variant,
            render_seconds=float(sum(p.seconds for p in passes)),
        )

    def _entry_info(self, request: ReferenceRequest) -> dict:
        """What entry.json adds to the identity, for humans and tools: the whole scene."""
        return {"scene_dict": scene_to_dict(request.scene), "scene_hash": scene_hash(request.scene)}


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


# ------------------------------------------------------------------- inspection and pruning (rtfit cache)
CACHE_NAMESPACES = {"images": "", "probes": "", "occlusion": "occlusion", "sky": "sky"}
"""What ``rtfit cache info`` reports, and the namespace folder each lives in (``""``: the root, where
`ReferenceCache` keeps radiance images and irradiance probes, told apart by ``entry.json``)."""


@dataclass(frozen=True)
class CacheEntry:
    """One `PassEntry` folder as found on disk."""

    path: Path
    namespace: str  # images, probes, occlusion, sky (or the folder's name for another namespace)
    passes: int  # complete passes (data and metadata both present)
    bytes: int  # every file of the folder
    last_used: float  # POSIX time: the latest mtime of entry.json and the pass files
    in_use: bool  # holds a live claim (`PassEntry.claim`): a running process is rendering a pass of it


@dataclass
class CacheSummary:
    root: Path
    entries: list[CacheEntry]
    other: dict[str, tuple[int, int]]  # files outside entries (sdf-grids, envmaps): folder -> (files, bytes)


def _is_hex(name: str, length: int) -> bool:
    return len(name) == length and all(c in "0123456789abcdef" for c in name)


def _entry_folders(base: Path):
    """``base/<key[:2]>/<key>/`` folders (a half-removed ``.KEY.removing-*`` folder is not one)."""
    for shard in sorted(base.iterdir()):
        if shard.is_dir() and _is_hex(shard.name, 2):
            for folder in sorted(shard.iterdir()):
                if folder.is_dir() and _is_hex(folder.name, 64) and folder.name.startswith(shard.name):
                    yield folder


def _scan_entry(folder: Path, namespace: str) -> CacheEntry:
    size, last, data, meta, in_use = 0, 0.0, set(), set(), False
    for f in folder.iterdir():
        try:
            st = f.stat()
        except FileNotFoundError:  # removed meanwhile (a temporary file renamed into place)
            continue
        size += st.st_size if f.is_file() else 0
        stem, _, ext = f.name.partition(".")
        if f.name == "entry.json" or (stem.startswith("pass-") and ext in ("json", "exr", "npz")):
            last = max(last, st.st_mtime)
        if f.name == ComputedEntry.RESULT:  # a `ComputedEntry`: one complete item
            last = max(last, st.st_mtime)
            data.add(stem)
            meta.add(stem)
        if stem.startswith("pass-"):
            if ext == "json":
                meta.add(stem)
            elif ext in ("exr", "npz"):
                data.add(stem)
            elif ext == "claim" and not PassEntry._claim_is_stale(f):
                in_use = True
    if namespace == "":
        try:
            quantity = json.loads((folder / "entry.json").read_text()).get("quantity")
        except (OSError, ValueError, AttributeError):
            quantity = None
        namespace = {"radiance": "images", "irradiance": "probes"}.get(quantity, "images/probes")
    return CacheEntry(folder, namespace, len(data & meta), size, last or folder.stat().st_mtime, in_use)


def scan_cache(root) -> CacheSummary:
    """Every entry under the cache ``root`` (all namespaces), and the other files beside them."""
    root = Path(root)
    entries: list[CacheEntry] = []
    other: dict[str, tuple[int, int]] = {}
    if not root.is_dir():
        return CacheSummary(root, entries, other)
    entries += [_scan_entry(f, "") for f in _entry_folders(root)]
    for sub in sorted(root.iterdir()):
        if not sub.is_dir() or _is_hex(sub.name, 2):
            continue
        found = [_scan_entry(f, sub.name) for f in _entry_folders(sub)]
        if found:
            entries += found
            continue
        files = [p for p in sub.rglob("*") if p.is_file()]
        other[sub.name] = (len(files), sum(p.stat().st_size for p in files))
    return CacheSummary(root, entries, other)


def _remove_tree(path: Path) -> None:
    for dirpath, dirnames, filenames in os.walk(path, topdown=False):
        for name in filenames:
            Path(dirpath, name).unlink(missing_ok=True)
        for name in dirnames:
            Path(dirpath, name).rmdir()
    path.rmdir()


def remove_entry(entry: CacheEntry) -> bool:
    """Remove a whole entry, never half of one: the folder is first renamed out of the cache's layout
    (``.KEY.removing-PID``, which no reader looks up), then deleted; if a process claimed one of its
    passes meanwhile, it is put back. Returns whether it was removed."""
    hidden = entry.path.with_name(f".{entry.path.name}.removing-{os.getpid()}")
    try:
        os.rename(entry.path, hidden)
    except FileNotFoundError:
        return False  # removed meanwhile by someone else
    if any(not PassEntry._claim_is_stale(c) for c in hidden.glob("pass-*.claim")):
        try:
            os.rename(hidden, entry.path)
            return False
        except OSError:
            pass  # the claimant recreated the folder already; its claim is in there, not in this one
    _remove_tree(hidden)
    try:
        hidden.parent.rmdir()  # the <key[:2]> shard, if it is now empty
    except OSError:
        pass
    return True


def leftover_removals(root) -> list[Path]:
    """Folders a pruning process left half-removed (``.KEY.removing-PID`` of a dead process)."""
    root = Path(root)
    if not root.is_dir():
        return []
    out = []
    for p in root.glob("**/.*.removing-*"):
        pid = p.name.rpartition("-")[2]
        if p.is_dir() and not (pid.isdigit() and int(pid) != os.getpid() and _pid_alive(int(pid))):
            out.append(p)
    return out


def remove_leftover(path: Path) -> None:
    """Delete one folder of `leftover_removals` (it is no entry any more: nothing reads it)."""
    _remove_tree(Path(path))


def prune_plan(
    entries: list[CacheEntry],
    *,
    older_than: float | None = None,
    max_size: int | None = None,
    now: float | None = None,
) -> tuple[list[CacheEntry], list[CacheEntry]]:
    """Which entries to remove, oldest last use first: every entry unused for more than ``older_than``
    seconds, then more of the oldest until the rest fit in ``max_size`` bytes. Entries in use (a live
    claim) are never chosen. Returns ``(remove, spared_in_use)``: the entries to remove, and those in
    use that the rule would otherwise have removed."""
    now = time.time() if now is None else now
    ordered = sorted(entries, key=lambda e: (e.last_used, str(e.path)))
    remove: list[CacheEntry] = []
    spared: list[CacheEntry] = []
    for e in ordered:
        if older_than is not None and now - e.last_used > older_than:
            (spared if e.in_use else remove).append(e)
    if max_size is not None:
        gone = {id(e) for e in remove}
        total = sum(e.bytes for e in ordered if id(e) not in gone)
        for e in ordered:
            if total <= max_size:
                break
            if id(e) in gone:
                continue
            if e.in_use:
                if all(s is not e for s in spared):
                    spared.append(e)
                continue
            remove.append(e)
            total -= e.bytes
    return remove, spared
