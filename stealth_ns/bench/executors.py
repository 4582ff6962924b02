"""Where ``stealth-ns bench attack`` trains its runs: here, one after another (``local``), or as Ray
tasks on a cluster (``ray``, with ``pip install 'stealth-ns[cluster]'``; see ``docs/design/cluster.md``).

The contract of both executors: ``open()``, then ``run(jobs, events)`` trains (or reuses) each
job's :class:`~stealth_ns.runs.training.TrainSpec` and yields one :class:`Outcome` per job as
it completes (the local executor in the jobs' order, Ray in completion order), then ``close()``.
``events`` hears when a job starts (:meth:`Events.started`), ns-train's output lines where they
are seen (local only) and every retry (Ray only). A job with ``blocked`` set (its scene cannot be
used) is not trained: it comes back at once as a failure.

Ray (imported only here, only for ``--executor ray``): each training is a task that reserves
``--ray-cpus-per-run`` CPUs (also its OpenMP threads) and ``--ray-gpus-per-run`` GPUs (default:
1 when the cluster has GPUs). The task calls :func:`~stealth_ns.runs.training.train` on its
node, so the run folders must be on storage every node sees at the same path (a shared file
system, as on a cluster) and stealth-ns must be installed on every node. Ray's own task retries
are off: the driver resubmits a run whose worker or node was lost (up to ``--ray-max-retries``
times) and a training that failed (up to ``--ray-train-retries`` times), and records each failed
attempt. Finished runs are reused by the driver without a task.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import os
import secrets
import socket
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.runs.training import TrainRecord, TrainSpec, finished_record, train

EXECUTORS: tuple[str, ...] = ("local", "ray")
INSTALL_HINT = "pip install 'stealth-ns[cluster]'"
DEFAULT_CPUS_PER_RUN = 1.0
DEFAULT_MAX_RETRIES = 3
DEFAULT_TRAIN_RETRIES = 1
#: Object store of a Ray instance started here: the tasks pass small records only.
LOCAL_OBJECT_STORE_BYTES = 128 * 1024**2
_RAY_FLAGS = {
    "address": "--ray-address",
    "cpus_per_run": "--ray-cpus-per-run",
    "gpus_per_run": "--ray-gpus-per-run",
    "max_retries": "--ray-max-retries",
    "train_retries": "--ray-train-retries",
}


# ------------------------------------------------------------------------------ options
@dataclass(frozen=True)
class ExecutorOptions:
    """``--executor`` and its ``--ray-*`` options (None: the default)."""

    name: str = "local"
    address: str | None = None
    """HOST:PORT of a Ray head (GCS), ray://HOST:PORT, ``auto`` or ``local``; None: ``RAY_ADDRESS``
    when set, else a new Ray instance on this machine."""
    cpus_per_run: float | None = None
    gpus_per_run: float | None = None
    """None: 1 when the cluster has GPUs, else 0."""
    max_retries: int | None = None
    train_retries: int | None = None

    @property
    def cpus(self) -> float:
        return DEFAULT_CPUS_PER_RUN if self.cpus_per_run is None else float(self.cpus_per_run)

    @property
    def lost_retries(self) -> int:
        return DEFAULT_MAX_RETRIES if self.max_retries is None else int(self.max_retries)

    @property
    def failed_retries(self) -> int:
        return DEFAULT_TRAIN_RETRIES if self.train_retries is None else int(self.train_retries)

    def resolved_address(self) -> str:
        """The address ``ray.init`` gets: ``--ray-address``, else ``RAY_ADDRESS``, else ``local``."""
        return self.address or os.environ.get("RAY_ADDRESS") or "local"

    def checked(self) -> ExecutorOptions:
        """These options, checked (:class:`StealthNSError` with one line for bad ones)."""
        if self.name not in EXECUTORS:
            raise StealthNSError(f"unknown executor {self.name!r}; executors: {', '.join(EXECUTORS)}")
        given = [flag for attr, flag in _RAY_FLAGS.items() if getattr(self, attr) is not None]
        if self.name != "ray":
            if given:
                raise StealthNSError(f"{', '.join(given)} only apply with --executor ray")
            return self
        if importlib.util.find_spec("ray") is None:
            raise StealthNSError(f"--executor ray needs Ray, which is not installed: {INSTALL_HINT}")
        if self.address is not None and not self.address.strip():
            raise StealthNSError("--ray-address is empty; give HOST:PORT, ray://HOST:PORT, auto or local")
        if not self.cpus > 0:
            raise StealthNSError(f"--ray-cpus-per-run must be positive, got {self.cpus_per_run}")
        if self.gpus_per_run is not None and not float(self.gpus_per_run) >= 0:
            raise StealthNSError(f"--ray-gpus-per-run must be 0 or more, got {self.gpus_per_run}")
        for attr in ("max_retries", "train_retries"):
            value = getattr(self, attr)
            if value is not None and (isinstance(value, bool) or int(value) != value or value < 0):
                raise StealthNSError(f"{_RAY_FLAGS[attr]} must be a non-negative integer, got {value!r}")
        return self

    def describe(self) -> str:
        """One line for the plan: ``local (...)`` or ``ray (address ..., resources, retries)``."""
        if self.name != "ray":
            return "local (one ns-train after another on this machine)"
        if self.address:
            where = f"address {self.address}"
        elif os.environ.get("RAY_ADDRESS"):
            where = f"address {os.environ['RAY_ADDRESS']} (from RAY_ADDRESS)"
        else:
            where = "a new Ray instance on this machine (no --ray-address; RAY_ADDRESS unset)"
        gpus = "auto" if self.gpus_per_run is None else f"{float(self.gpus_per_run):g}"
        return (
            f"ray, {where}; per run {self.cpus:g} CPU(s), GPUs {gpus}; a run is resubmitted up to "
            f"{self.lost_retries}x after a lost worker, {self.failed_retries}x after a failed training"
        )


# ------------------------------------------------------------------------------ the contract
@dataclass(frozen=True)
class Job:
    """One run to train (or reuse)."""

    key: str
    spec: TrainSpec
    blocked: str | None = None
    """Why it cannot be trained (its scene failed); it then comes back as a failure, untrained."""


@dataclass
class Outcome:
    """How a job ended: its record, or an error."""

    job: Job
    record: TrainRecord | None = None
    error: str | None = None
    blocked: bool = False
    attempts: list[str] = field(default_factory=list)
    """The failed attempts (Ray), one line each, the final failure included."""
    worker: dict[str, Any] | None = None
    """Where it trained (Ray): host, pid, node_id."""


class Events(Protocol):
    """What the bench hears from an executor while it runs."""

    def started(self, job: Job) -> None: ...

    def line_callback(self, job: Job) -> Callable[[str], None] | None: ...

    def retrying(self, job: Job, attempt: int, reason: str) -> None: ...


class Executor(Protocol):
    name: str
    sequential: bool

    def open(self) -> None: ...

    def run(self, jobs: Sequence[Job], events: Events) -> Iterator[Outcome]: ...

    def record(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


class LocalExecutor:
    """One ``ns-train`` after another in this process's machine, in the jobs' order."""

    name = "local"
    sequential = True

    def open(self) -> None:
        """Nothing to connect to."""

    def close(self) -> None:
        """Nothing to release."""

    def record(self) -> dict[str, Any]:
        return {"name": "local"}

    def run(self, jobs: Sequence[Job], events: Events) -> Iterator[Outcome]:
        """Train each job in turn (``ns-train`` output lines go to ``events``)."""
        for job in jobs:
            events.started(job)
            if job.blocked is not None:
                yield Outcome(job, error=job.blocked, blocked=True)
                continue
            try:
                record = train(job.spec, stream=False, on_line=events.line_callback(job))
            except StealthNSError as err:
                yield Outcome(job, error=str(err))
                continue
            yield Outcome(job, record=record)


def make_executor(options: ExecutorOptions) -> Executor:
    """The executor of ``options`` (not opened yet)."""
    return RayExecutor(options) if options.name == "ray" else LocalExecutor()


# ------------------------------------------------------------------------------ Ray
def import_ray() -> Any:
    """The ``ray`` module, with Ray's usage statistics off (:class:`StealthNSError` without Ray)."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    try:
        import ray
    except ImportError:
        raise StealthNSError(f"--executor ray needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def check_reachable(address: str, timeout: float = 10.0) -> None:
    """Fail fast (one line) when a HOST:PORT address does not answer: ``ray.init`` would retry forever."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[1] if "://" in address else address
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise StealthNSError(
            f"bad Ray address {address!r}: give HOST:PORT (the head's port, 6379 by default), "
            "ray://HOST:PORT, auto or local"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as err:
        raise StealthNSError(
            f"cannot reach the Ray cluster at {address}: {err.strerror or err} "
            "(is `ray start --head` running there, and the port open to this machine?)"
        ) from None


def _where() -> dict[str, Any]:
    """This process's host, pid and (in a Ray worker) Ray node id."""
    info: dict[str, Any] = {"host": socket.gethostname(), "pid": os.getpid()}
    ray = sys.modules.get("ray")
    # only when connected: get_runtime_context() would start a Ray instance otherwise
    if ray is not None and getattr(ray, "is_initialized", lambda: False)():
        info["node_id"] = ray.get_runtime_context().get_node_id()
    return info


def train_task(spec: TrainSpec) -> dict[str, Any]:
    """The Ray task: train (or reuse) ``spec`` on this node. A failed training is returned, not
    raised, so that an exception from the task means a lost worker or node."""
    where = _where()
    try:
        record = train(spec, stream=False)
    except Exception as err:  # reported by the driver with the node it happened on
        error = str(err) if isinstance(err, StealthNSError) else f"{type(err).__name__}: {err}"
        return {"record": None, "error": error, "worker": where}
    return {"record": record, "error": None, "worker": where}


@dataclass
class _Attempts:
    """A job on Ray and its failed attempts so far."""

    job: Job
    lost: int = 0
    failed: int = 0
    failures: list[str] = field(default_factory=list)

    @property
    def number(self) -> int:
        return self.lost + self.failed + 1


class RayExecutor:
    """Every training a Ray task, run in parallel as the cluster's resources allow."""

    name = "ray"
    sequential = False

    def __init__(self, options: ExecutorOptions) -> None:
        self.options = options
        self._ray: Any = None
        self._remote: Any = None
        self._owned = False
        self._env_set: list[str] = []
        self._info: dict[str, Any] = {"name": "ray", "address": options.resolved_address()}
        self.gpus = 0.0

    @property
    def threads(self) -> int:
        return max(1, round(self.options.cpus))

    def open(self) -> None:
        """Connect to the cluster (or start a Ray instance here) and settle the resources per run."""
        address = self.options.resolved_address()
        if address == "local" and "ray" not in sys.modules:
            self._private_token()  # read by Ray when it is imported
        ray = import_ray()
        if not ray.is_initialized():
            check_reachable(address)
            kwargs: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.WARNING}
            if address == "local":
                kwargs.update(
                    include_dashboard=False,
                    object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                    _node_ip_address="127.0.0.1",
                )
            try:
                ray.init(address=address, **kwargs)
            except Exception as err:
                self._restore_env()
                raise StealthNSError(
                    f"cannot connect to the Ray cluster at {address}: {_first_line(err)}"
                ) from None
            self._owned = True
        self._ray = ray
        self._settle_resources()

    def _private_token(self) -> None:
        """A Ray instance started here gets a fresh random token in this process's environment (its
        workers inherit it; Ray would otherwise write one to ~/.ray/auth_token)."""
        if any(os.environ.get(v) for v in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")):
            return
        os.environ["RAY_AUTH_MODE"] = "token"
        os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
        self._env_set = ["RAY_AUTH_MODE", "RAY_AUTH_TOKEN"]

    def _restore_env(self) -> None:
        for name in self._env_set:
            os.environ.pop(name, None)
        self._env_set = []

    def _settle_resources(self) -> None:
        """GPUs per run (auto: 1 when the cluster has some), the task, and a warning when no node
        can take a run now (an autoscaling cluster may still add one)."""
        ray, opts = self._ray, self.options
        total = ray.cluster_resources()
        nodes = [n for n in ray.nodes() if n.get("Alive", True)]
        auto_gpus = float(total.get("GPU", 0) >= 1)
        self.gpus = auto_gpus if opts.gpus_per_run is None else float(opts.gpus_per_run)
        fits = [
            n
            for n in nodes
            if n["Resources"].get("CPU", 0) >= opts.cpus and n["Resources"].get("GPU", 0) >= self.gpus
        ]
        if not fits:
            print(
                f"warning: no node of the Ray cluster has {opts.cpus:g} CPU(s) and {self.gpus:g} GPU(s) "
                f"for a run (cluster: {_resources(total)}); the runs wait until such a node joins",
                file=sys.stderr,
                flush=True,
            )
        self._remote = ray.remote(train_task)
        self._info.update(
            cpus_per_run=opts.cpus,
            gpus_per_run=self.gpus,
            threads_per_run=self.threads,
            max_retries=opts.lost_retries,
            train_retries=opts.failed_retries,
            nodes=len(nodes),
            cluster_resources={k: total[k] for k in ("CPU", "GPU") if k in total},
            ray=getattr(ray, "__version__", None),
        )

    def record(self) -> dict[str, Any]:
        return dict(self._info)

    def close(self) -> None:
        """Disconnect (and stop the Ray instance started here) when ``open`` connected."""
        if self._owned and self._ray is not None:
            self._ray.shutdown()
            self._owned = False
        self._restore_env()

    def _submit(self, job: Job) -> Any:
        spec = dataclasses.replace(job.spec, threads=self.threads)
        task = self._remote.options(
            num_cpus=self.options.cpus,
            num_gpus=self.gpus,
            max_retries=0,  # retried by the driver, which records every failed attempt
            retry_exceptions=False,
            name=f"stealth-ns train {job.key}",
        )
        return task.remote(spec)

    def run(self, jobs: Sequence[Job], events: Events) -> Iterator[Outcome]:
        """Submit the runs to train, then yield the blocked and finished ones (reused from the shared
        file system, no task), then the others as their tasks complete (retrying)."""
        pending: dict[Any, _Attempts] = {}
        at_once: list[Outcome] = []
        for job in jobs:
            events.started(job)
            if job.blocked is not None:
                at_once.append(Outcome(job, error=job.blocked, blocked=True))
            elif (record := finished_record(job.spec)) is not None:
                at_once.append(Outcome(job, record=record))
            else:
                pending[self._submit(job)] = _Attempts(job)
        try:
            yield from at_once  # their metrics are computed while the cluster trains
            while pending:
                ready, _ = self._ray.wait(list(pending), num_returns=1, timeout=1.0)
                for ref in ready:
                    outcome = self._settle(pending, ref, events)
                    if outcome is not None:
                        yield outcome
        finally:  # Ctrl-C, or the bench stopped: the tasks get KeyboardInterrupt, ns-train stops
            self._cancel(list(pending))

    def _settle(self, pending: dict[Any, _Attempts], ref: Any, events: Events) -> Outcome | None:
        """The outcome of a completed task, or None when it was resubmitted."""
        att = pending.pop(ref)
        worker = None
        try:
            result = self._ray.get(ref)
        except Exception as err:  # the task's worker or node was lost (a Ray system failure)
            att.lost += 1
            reason = f"worker lost: {_first_line(err)}"
            retry = att.lost <= self.options.lost_retries
        else:
            worker = result.get("worker")
            if result.get("error") is None:
                return Outcome(att.job, record=result["record"], attempts=att.failures, worker=worker)
            att.failed += 1
            host = f" (on {worker['host']})" if worker else ""
            reason = f"training failed{host}: {result['error']}"
            retry = att.failed <= self.options.failed_retries
        att.failures.append(f"attempt {att.number - 1}: {reason}")
        if not retry:
            tries = att.number - 1
            error = reason if tries == 1 else f"{reason} ({tries} attempts)"
            return Outcome(att.job, error=error, attempts=att.failures, worker=worker)
        events.retrying(att.job, att.number, reason)
        pending[self._submit(att.job)] = att
        return None

    def _cancel(self, refs: list[Any]) -> None:
        if not refs:
            return
        for ref in refs:
            try:
                self._ray.cancel(ref)
            except Exception:  # already finished or gone
                pass
        try:  # give the tasks a moment to stop their ns-train before the driver disconnects
            self._ray.wait(refs, num_returns=len(refs), timeout=10)
        except Exception:
            pass


def _resources(total: dict[str, Any]) -> str:
    return ", ".join(f"{total.get(k, 0):g} {k}" for k in ("CPU", "GPU"))
