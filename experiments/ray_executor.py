"""``--executor ray``: run a job list on a Ray cluster, one long-lived worker per GPU.

Needs the optional extra ``pip install 'rtfit[ray]'``; without it, asking for this executor is a
one-line error naming the extra.

Workers
    On a cluster with GPUs, one actor per GPU (``num_gpus=1``: Ray sets its ``CUDA_VISIBLE_DEVICES``),
    otherwise ``workers`` CPU actors (default: one per CPU of the cluster) that split a node's cores.
    Each actor is a long-lived process with its own Dr.Jit kernel-cache directory (a shared kernel
    cache can corrupt, drjit #115/#130/#162), so kernels compile once per worker, not once per job.

Jobs
    A :class:`~rtfit.experiments.jobs.Job` travels as plain data (its function's import path
    ``module:qualname`` and keyword arguments: scene text, numbers, arrays, paths); its result is plain
    data. Workers import ``rtfit`` themselves,
    so every node needs the same rtfit installed (or a Ray ``runtime_env``), and the reference cache
    directory should be on a filesystem the nodes share: its entries are written pass by pass with an
    atomic rename, so two workers never leave a half-written entry (the last complete write wins).

Faults
    A job that raises fails with its own one-line error (not retried: it would fail again). A worker
    that dies (killed, out of memory, node lost) is replaced by a fresh actor and its job is resubmitted
    to the next free worker, up to ``max_attempts`` times in all.
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
import time
import warnings

from rtfit.reference.io import held_output

from .jobs import MAX_ATTEMPTS, Job, JobTracker, Outcome, error_line, run_path, values_or_raise

RAY_EXTRA_HINT = "--executor ray needs Ray: pip install 'rtfit[ray]'"

CONNECT_TIMEOUT_S = 10.0
"""Seconds to wait for a Ray cluster to answer at ``--address`` (``$RTFIT_RAY_TIMEOUT`` overrides): the
TCP check of the address (`check_address`, before anything runs), then ``ray.init`` itself
(`RayExecutor`), each a one-line error when it runs out, instead of Ray's minutes of retries."""

DEFAULT_PORTS = {"ray": 10001, "": 6379}  # Ray Client (ray://) and the GCS port


def connect_timeout() -> float:
    """`CONNECT_TIMEOUT_S`, or ``$RTFIT_RAY_TIMEOUT`` seconds (a positive number)."""
    text = os.environ.get("RTFIT_RAY_TIMEOUT")
    if not text:
        return CONNECT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise ValueError(f"RTFIT_RAY_TIMEOUT={text!r}: expected a positive number of seconds")
    return value


def address_endpoint(address: str) -> tuple[str, int] | None:
    """(host, port) that a Ray address names (``ray://host[:port]`` → Ray Client, 10001 by default;
    ``host[:port]`` → the GCS, 6379 by default); None for ``auto`` and ``local`` (Ray finds those itself).
    A malformed address is a one-line ``ValueError``."""
    text = address.strip()
    if text in ("auto", "local"):
        return None
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "", text
    elif scheme != "ray":
        raise ValueError(f"--address {address!r}: expected host:port or ray://host:port")
    host, port = rest.rstrip("/"), str(DEFAULT_PORTS[scheme])
    if host.startswith("["):  # [IPv6]:port
        inner, _, tail = host[1:].partition("]")
        host, port = inner, tail[1:] if tail.startswith(":") else port
    elif host.count(":") == 1:
        host, port = host.split(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--address {address!r}: expected host:port or ray://host:port")
    return host, int(port)


def check_address(address: str, timeout: float | None = None, option: str = "--address"):
    """A one-line ``ValueError`` unless something accepts a TCP connection at ``address`` within
    ``timeout`` seconds (default `connect_timeout`): a wrong host or port fails in seconds, before
    anything runs or is written, instead of hanging in Ray's retries. ``option``: how the message names
    where the address came from (``--address``, or ``$RAY_ADDRESS``, which Ray reads by itself)."""
    endpoint = address_endpoint(address)
    if endpoint is None:
        return
    timeout = connect_timeout() if timeout is None else timeout
    try:
        with socket.create_connection(endpoint, timeout=timeout):
            pass
    except TimeoutError:
        raise ValueError(
            f"{option} {address}: no answer from {endpoint[0]}:{endpoint[1]} within {timeout:g} s "
            "(is the Ray cluster up? $RTFIT_RAY_TIMEOUT sets the wait)"
        ) from None
    except OSError as e:
        raise ValueError(
            f"{option} {address}: cannot connect to {endpoint[0]}:{endpoint[1]} ({e.strerror or e})"
        ) from None


def _init_within(ray, timeout: float, address: str, option: str = "--address", **kwargs):
    """``ray.init(address=address, **kwargs)``, or a one-line ``ValueError`` after ``timeout`` seconds
    (the call runs in a daemon thread: a cluster that accepts the connection but never completes the
    handshake cannot hold the command)."""
    box: dict = {}

    def target():
        try:
            box["value"] = ray.init(address=address, **kwargs)
        except BaseException as e:  # handed to the caller's thread
            box["error"] = e

    thread = threading.Thread(target=target, name="rtfit-ray-init", daemon=True)
    # Ray's C++ client prints a line a second while it retries an address that answers TCP but is no
    # cluster (issue 32: 21 lines before the error): held, and shown only if it connects
    with held_output() as held:
        thread.start()
        thread.join(timeout)
        held.ok = not thread.is_alive() and "error" not in box
    if thread.is_alive():
        raise ValueError(f"{option} {address}: Ray did not connect within {timeout:g} s")
    if "error" in box:
        e = box["error"]
        raise ValueError(f"{option} {address}: {error_line(e)}") from e
    return box["value"]


def _import_ray():
    try:
        import ray  # ray: optional extra rtfit[ray], and ≈ 2 s to import
    except ImportError:
        raise ValueError(RAY_EXTRA_HINT) from None
    return ray


class _Worker:
    """The actor body: a private kernel cache, a thread budget on CPU, then jobs one at a time."""

    def __init__(self, threads: int | None):
        os.environ["DRJIT_CACHE_DIR"] = tempfile.mkdtemp(prefix="rtfit-drjit-ray-")
        self.threads = threads

    def pid(self) -> int:
        return os.getpid()

    def run(self, path: str, kwargs: dict):
        if self.threads:
            # drjit stays lazy: importing it starts CUDA's initialisation (reading CUDA_VISIBLE_DEVICES),
            # which must happen in the actor after Ray has assigned its GPU, not when this module loads.
            import drjit as dr

            if dr.thread_count() != self.threads:
                dr.set_thread_count(self.threads)
        return run_path(path, kwargs)


class RayExecutor:
    """Jobs on Ray actors; ``address`` names an existing cluster (``ray://…`` or ``host:port``),
    ``None`` connects to ``RAY_ADDRESS`` if set, else starts a local cluster on this machine."""

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        progress: bool = False,
        max_attempts: int = MAX_ATTEMPTS,
        num_cpus: int | None = None,
        num_gpus: int | None = None,
    ):
        ray = _import_ray()
        self._ray = ray
        self.progress = progress
        self.max_attempts = max_attempts
        if not ray.is_initialized():
            # Ray starts its daemons with fork+exec; Python warns about fork when JAX threads exist.
            warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
            kwargs = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
            if address:
                check_address(address)
                _init_within(ray, 3 * connect_timeout(), address, **kwargs)
            elif os.environ.get("RAY_ADDRESS"):  # the same time limits as --address (issue 32: > 300 s)
                env = os.environ["RAY_ADDRESS"]
                check_address(env, option="$RAY_ADDRESS")
                _init_within(ray, 3 * connect_timeout(), env, "$RAY_ADDRESS", **kwargs)
            else:
                if num_gpus is not None:
                    kwargs["num_gpus"] = num_gpus  # a local cluster using only the first num_gpus GPUs
                ray.init(num_cpus=num_cpus or os.cpu_count() or 1, **kwargs)
            self._owns_ray = True
        else:
            self._owns_ray = False
        resources = ray.cluster_resources()
        self.gpus = int(resources.get("GPU", 0))
        cpus = int(resources.get("CPU", 1))
        if self.gpus:
            # A GPU worker also does CPU work (fits, metrics, figures): give it its share of the
            # cores, or Ray would pin it to one (OMP_NUM_THREADS=1 for a num_cpus=1 actor).
            self.workers = self.gpus
            self._options = {"num_gpus": 1, "num_cpus": max(1, cpus // self.gpus)}
            self._threads = None
        else:
            self.workers = workers or cpus
            share = max(1, cpus // self.workers)
            self._options = {"num_cpus": min(share, cpus)}
            self._threads = share
        self._actor_class = ray.remote(**self._options)(_Worker)
        self._actors = [self._new_actor() for _ in range(self.workers)]
        self._pids = ray.get([a.pid.remote() for a in self._actors])
        self._busy: dict[int, str] = {}  # actor slot -> label of the job it runs

    def _new_actor(self):
        return self._actor_class.options(max_restarts=0, max_task_retries=0).remote(self._threads)

    def worker_pids(self) -> list[int]:
        """PIDs of the worker processes, one per slot (for monitoring and fault-injection tests)."""
        return list(self._pids)

    def busy_pids(self) -> dict[int, str]:
        """PID → label of the job that worker is running now."""
        return {self._pids[slot]: label for slot, label in list(self._busy.items())}

    def run_all(self, jobs: list[Job], desc: str = "jobs", _exceptions: dict | None = None) -> list[Outcome]:
        ray = self._ray
        from ray.exceptions import RayActorError, RayTaskError, WorkerCrashedError

        lost_worker = (RayActorError, WorkerCrashedError)
        paths = [job.path for job in jobs]  # a function no worker could import: refused before any job runs
        tracker = JobTracker(len(jobs), desc, self.progress)
        outcomes: list[Outcome | None] = [None] * len(jobs)
        attempts = [0] * len(jobs)
        queue = list(range(len(jobs)))
        idle = list(range(len(self._actors)))
        in_flight: dict = {}  # object ref -> (job index, actor slot, start time)
        try:
            while queue or in_flight:
                while queue and idle:
                    i, slot = queue.pop(0), idle.pop(0)
                    attempts[i] += 1
                    ref = self._actors[slot].run.remote(paths[i], jobs[i].kwargs)
                    in_flight[ref] = (i, slot, time.perf_counter())
                    self._busy[slot] = jobs[i].label or str(i)
                    tracker.started()
                ready, _ = ray.wait(list(in_flight), num_returns=1)
                ref = ready[0]
                i, slot, t0 = in_flight.pop(ref)
                self._busy.pop(slot, None)
                try:
                    value = ray.get(ref)
                except RayTaskError as e:
                    cause = e.cause if isinstance(getattr(e, "cause", None), BaseException) else e
                    if isinstance(cause, lost_worker):
                        self._lost(i, slot, cause, attempts, outcomes, queue, tracker, jobs)
                    else:
                        outcomes[i] = Outcome.raised(i, jobs[i].label, cause, attempts[i], t0)
                        if _exceptions is not None:
                            _exceptions[i] = cause
                        tracker.finished(False)
                    idle.append(slot)
                    continue
                except lost_worker as e:
                    self._lost(i, slot, e, attempts, outcomes, queue, tracker, jobs)
                    idle.append(slot)
                    continue
                outcomes[i] = Outcome.returned(i, jobs[i].label, value, attempts[i], t0)
                tracker.finished(True)
                idle.append(slot)
        finally:
            tracker.close()
        return outcomes  # type: ignore[return-value]

    def _lost(self, i, slot, exc, attempts, outcomes, queue, tracker, jobs):
        """A worker died under job ``i``: replace the actor; retry the job or give up on it."""
        try:
            self._ray.kill(self._actors[slot], no_restart=True)
        except Exception:  # it is already gone
            pass
        self._actors[slot] = self._new_actor()
        self._pids[slot] = self._ray.get(self._actors[slot].pid.remote())
        if attempts[i] >= self.max_attempts:
            outcomes[i] = Outcome.worker_died(i, jobs[i].label, exc, attempts[i])
            tracker.finished(False)
        else:
            queue.insert(0, i)
            tracker.requeued()

    def map(self, jobs: list[Job], desc: str = "jobs") -> list:
        exceptions: dict[int, BaseException] = {}
        return values_or_raise(self.run_all(jobs, desc, exceptions), exceptions)

    def close(self):
        for actor in self._actors:
            try:
                self._ray.kill(actor)
            except Exception:
                pass
        self._actors = []
        if self._owns_ray:
            self._ray.shutdown()
