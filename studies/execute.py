"""The studies' run engine: jobs that are pure functions of their description, run on Dask and
cached on disk.

A :class:`Job` (a frozen, picklable description of one run: scenario, overrides, seed, which
controllers) is run by a module-level runner function that returns a :class:`RunOutcome` (a
JSON summary or the error, and maybe a plot log). :func:`execute_jobs` reads the finished jobs
from a :class:`RunCache` (``<key>.json`` per job, key = SHA-256 of the job's
:meth:`Job.key_document`, the cache schema and the package versions: :func:`job_key`), runs the
others in this process, on a Dask ``LocalCluster`` of spawned single-thread worker processes
(PyBullet clients and crocoddyl objects must never be forked mid-state), or on the workers of a
running scheduler (``scheduler=``, ``--scheduler``), and caches each as it ends: a study that is
killed resumes from its cache. The polishing study (:mod:`studies.study`), the impact study
(:mod:`studies.impact_study`) and the exploration (:mod:`studies.exploration`) all run through
it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from ffmpc_core.errors import ConfigError

if TYPE_CHECKING:
    from distributed import Client, LocalCluster
    from tqdm import tqdm

__all__ = [
    "CACHE_SCHEMA",
    "Job",
    "RunBatch",
    "RunCache",
    "RunOutcome",
    "canonical_json",
    "dask_cluster",
    "check_output_dir",
    "prepare_output_dir",
    "study_cache",
    "write_json",
    "worker_count",
    "execute_jobs",
    "job_key",
    "write_atomic",
]


class Job(Protocol):
    """One run of a study, a pure function of this description (frozen and picklable)."""

    def key_document(self) -> dict[str, Any]:
        """Everything the run's result depends on, JSON-able (the fully resolved configuration,
        what it sends back): two jobs with equal documents compute the same result."""
        ...

    def description(self) -> dict[str, Any]:
        """What the job is, JSON-able (kept in its cache entry)."""
        ...

    @property
    def label(self) -> str:
        """A short name for the progress bar."""
        ...

    @property
    def cost_rank(self) -> int:
        """Submission order: the slowest jobs (lowest rank) first, so the pool's tail is short."""
        ...


JobT = TypeVar("JobT", bound=Job)


@dataclass
class RunOutcome:
    """What a worker sends back for a job: the run's JSON summary or its error, and maybe a plot
    log (named float series)."""

    spec: Any  # the Job
    summary: dict | None = None
    error: str | None = None
    plot_log: dict[str, np.ndarray] | None = field(default=None, repr=False)
    #: True when read back from the run cache instead of run now.
    cached: bool = field(default=False, compare=False)

    @property
    def ok(self) -> bool:
        return self.summary is not None


#: Version of what a cache entry holds and of how a run computes it: bump it when a code change
#: alters run results without a change of the package version (old entries are then unused).
CACHE_SCHEMA = 1


def _plain(value: Any) -> Any:
    """numpy values as the JSON types they hold (the default of :func:`canonical_json`)."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def canonical_json(doc: Any) -> str:
    """Sorted-key, compact JSON: the same content always gives the same text."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=True, default=_plain)


def _key_versions() -> dict[str, str | None]:
    """The ffmpc version and the installed versions of the numerical packages (part of a key)."""
    from importlib import metadata

    from ffmpc_core.selfcheck import installed_versions

    try:
        own = metadata.version("ffmpc")
    except metadata.PackageNotFoundError:
        own = None
    return {"ffmpc": own, **installed_versions()}


def job_key(job: Job, versions: dict[str, str | None] | None = None) -> str:
    """The cache key of a run: SHA-256 (hex, 32 digits) of the canonical JSON of the job's
    :meth:`Job.key_document` (everything its result depends on: the fully resolved scenario,
    what the run sends back), the cache schema and the package versions. Two jobs with the same
    key compute the same result."""
    doc = {
        "schema": CACHE_SCHEMA,
        "versions": _key_versions() if versions is None else versions,
        **job.key_document(),
    }
    return hashlib.sha256(canonical_json(doc).encode("utf-8")).hexdigest()[:32]


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same directory and a rename:
    a reader (or a restart after a kill) sees the old file or the whole new one, never a part."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _outcome_entry(key: str, outcome: RunOutcome) -> dict[str, Any]:
    """A run's outcome as a JSON-friendly cache entry (plot logs as lists of floats)."""
    return {
        "schema": CACHE_SCHEMA,
        "key": key,
        "spec": outcome.spec.description(),
        "summary": outcome.summary,
        "error": outcome.error,
        "plot_log": None
        if outcome.plot_log is None
        else {name: np.asarray(v, dtype=float).tolist() for name, v in outcome.plot_log.items()},
    }


def _outcome_from_entry(spec: Job, entry: dict[str, Any], cached: bool) -> RunOutcome:
    logs = entry.get("plot_log")
    return RunOutcome(
        spec,
        summary=entry.get("summary"),
        error=entry.get("error"),
        plot_log=None if logs is None else {k: np.array(v, dtype=float) for k, v in logs.items()},
        cached=cached,
    )


class RunCache:
    """Finished runs on disk, one ``<key>.json`` per run (see :func:`run_key`).

    An entry is written atomically (:func:`write_atomic`) by the process that collects the
    results, so a study killed at any moment leaves whole entries only; a restart reads them
    back instead of running them again. Floats survive the JSON round trip bit for bit.
    """

    def __init__(self, directory: str | os.PathLike) -> None:
        self.directory = Path(directory)

    def path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        """The entry of ``key``, or None if absent or unreadable (then the run is run again)."""
        try:
            text = self.path(key).read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        try:
            entry = json.loads(text)
        except json.JSONDecodeError:
            return None
        if not isinstance(entry, dict) or entry.get("key") != key:
            return None
        return entry

    def put(self, key: str, entry: dict[str, Any]) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        write_atomic(self.path(key), json.dumps(entry, allow_nan=True) + "\n")


@dataclass
class RunBatch:
    """Outcomes of :func:`execute_specs` in the order of the specs, and how they were obtained.

    ``cached`` runs were read from the cache, ``executed`` ones were run now; ``cluster`` says
    where ("in-process", "LocalCluster" or the scheduler address), ``workers`` how many worker
    processes it had, ``dashboard`` the Dask dashboard link (None without one).
    """

    outcomes: list[RunOutcome]
    cached: int
    executed: int
    cluster: str
    workers: int
    dashboard: str | None = None

    def execution(self, cache: RunCache | None) -> dict[str, Any]:
        """How the runs were obtained, for a results document's ``execution``: cached and
        executed counts, the cluster, and the run cache's directory (None without one)."""
        return {
            "cached": self.cached,
            "executed": self.executed,
            "cluster": self.cluster,
            "cache_dir": None if cache is None else str(cache.directory),
        }


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


#: How long to try to reach a running Dask scheduler (s).
SCHEDULER_TIMEOUT_S = 20.0


def _dask_client(workers: int, scheduler: str | None) -> tuple[Client, LocalCluster | None]:
    """A ``distributed`` client and the LocalCluster it owns (None with ``scheduler``)."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from exc
        return client, None
    # Processes (PyBullet and crocoddyl are not thread-safe), one thread each, spawned; bound
    # to this machine (the dashboard too, never 0.0.0.0).
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    )
    try:
        return Client(cluster), cluster
    except BaseException:
        cluster.close()
        raise


def _dashboard(client: Client) -> str | None:
    try:
        import bokeh  # noqa: F401  (the dashboard is served only with bokeh installed)
    except ImportError:
        return None
    return client.dashboard_link


def execute_jobs(
    specs: Sequence[JobT],
    runner: Callable[[JobT], RunOutcome],
    workers: int | None = None,
    progress: bool = True,
    *,
    scheduler: str | None = None,
    cache: RunCache | None = None,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    client: Client | None = None,
) -> RunBatch:
    """Run every job not in ``cache`` (unless ``fresh``) with ``runner`` (a module-level
    function: Dask pickles it) and store each new result there.

    Args:
        workers: worker processes of a Dask ``LocalCluster`` (default ``os.cpu_count()``);
            ``1`` runs in this process, without a cluster. Workers are *spawned*: a script
            calling this needs the ``if __name__ == "__main__":`` guard.
        scheduler: address of a running Dask scheduler (``tcp://host:port``): its workers run
            the specs (they need ffmpc installed); excludes ``workers``.
        cache: finished runs, read before and written as each run ends (by this process).
        fresh: run everything again (the new results still go to ``cache``).
        progress: a tqdm bar on stderr and, by default, the lines of ``announce``.
        announce: where the one-line messages go (cluster, dashboard, cached vs to run).
        client: a Dask client kept open across batches (:func:`dask_cluster`, e.g. one per
            tuning search): its workers run the jobs and it is left open; excludes ``workers``
            and ``scheduler``.
    """
    from tqdm import tqdm

    if client is not None and (scheduler is not None or workers is not None):
        raise ConfigError("a shared Dask client excludes workers and scheduler")
    workers = worker_count(workers, scheduler)
    if not specs:
        raise ConfigError("a study needs at least one run")
    say = announce or (_stderr if progress else (lambda _text: None))
    outcomes: list[RunOutcome | None] = [None] * len(specs)
    keys: list[str | None] = [None] * len(specs)
    if cache is not None:
        versions = _key_versions()
        keys = [job_key(s, versions) for s in specs]
        if not fresh:
            for i, (spec, key) in enumerate(zip(specs, keys, strict=True)):
                entry = cache.get(key) if key is not None else None
                if entry is not None:
                    outcomes[i] = _outcome_from_entry(spec, entry, cached=True)
    todo = sorted(
        (i for i, o in enumerate(outcomes) if o is None), key=lambda i: specs[i].cost_rank
    )
    n_cached = len(specs) - len(todo)
    if not todo:
        where, workers = "none (every run from the cache)", 0
    elif client is not None:
        where = client.scheduler.address
    elif scheduler is None and (workers == 1 or len(todo) == 1):
        where, workers = "in-process", 1
    else:
        where = scheduler or "LocalCluster"
    if cache is not None:
        say(f"{len(specs)} runs: {n_cached} from the cache {cache.directory}, {len(todo)} to run")

    def finish(i: int, outcome: RunOutcome, bar: tqdm) -> None:
        # Every outcome goes through the JSON of a cache entry: a run read back from the cache
        # and a run done now give equal objects.
        entry = json.loads(json.dumps(_outcome_entry(keys[i] or "", outcome), allow_nan=True))
        key = keys[i]
        if cache is not None and key is not None:
            cache.put(key, entry)
        outcomes[i] = _outcome_from_entry(specs[i], entry, cached=False)
        bar.set_postfix_str(specs[i].label, refresh=False)
        bar.update()

    def new_bar() -> tqdm:
        return tqdm(
            total=len(specs),
            initial=n_cached,
            file=sys.stderr,
            disable=not progress,
            unit="run",
            smoothing=0,
        )

    dashboard = None
    if todo and where == "in-process":
        with new_bar() as bar:
            for i in todo:
                finish(i, runner(specs[i]), bar)
    elif todo:
        from distributed import as_completed as dask_completed

        with ExitStack() as stack:
            if client is None:  # a cluster for this batch (LocalCluster: no more than the runs)
                count = None if scheduler is not None else min(workers, len(todo))
                active = stack.enter_context(dask_cluster(count, scheduler, quiet=True))
                assert active is not None  # two runs or more, or a scheduler: never in-process
            else:
                active = client
            workers, dashboard = _announce(active, where, say)
            futures = []
            try:
                index = {}
                for rank, i in enumerate(todo):
                    future = active.submit(runner, specs[i], pure=False, priority=len(todo) - rank)
                    futures.append(future)
                    index[future.key] = i
                with new_bar() as bar:
                    for future in dask_completed(futures):
                        finish(index[future.key], future.result(), bar)
            finally:
                # Done, a bug or Ctrl-C: queued runs are dropped, the finished ones are cached
                # (then the batch's own cluster closes; a shared client stays open).
                active.cancel(futures)
    done = [o for o in outcomes if o is not None]
    return RunBatch(done, n_cached, len(todo), where, workers, dashboard)


def check_output_dir(out: str | os.PathLike, force: bool = False, resume: bool = False) -> None:
    """Refuse an existing output directory unless ``force``, or unless ``resume`` and it holds
    an interrupted study (a ``cache/`` and no ``results.json``): ConfigError."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"output path {path} is not a directory")
    interrupted = (path / "cache").is_dir() and not (path / "results.json").exists()
    if path.exists() and not force and not (resume and interrupted):
        raise ConfigError(
            f"output directory {path} already exists; pass --force to overwrite (an interrupted "
            "study, with a cache/ and no results.json, resumes by running the same command)"
        )
    from ffmpc_ros.preflight import check_output

    # writable: in the directory itself, or where it will be made (its nearest existing parent)
    probe = path if path.is_dir() else next(p for p in path.parents if p.exists())
    check_output(probe / ".ffmpc-out-check", what="--out")


def prepare_output_dir(out: str | os.PathLike, force: bool = False, resume: bool = False) -> Path:
    """Create the output directory; refuse an existing one unless ``force`` (then files in it
    are overwritten) or ``resume`` of an interrupted study (see :func:`check_output_dir`)."""
    check_output_dir(out, force, resume)
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    return path


def worker_count(workers: int | None, scheduler: str | None) -> int:
    """The worker processes asked for: ``workers`` (default ``os.cpu_count()``); ConfigError
    for fewer than 1, or with a ``scheduler`` too (a running cluster has its own workers)."""
    if scheduler is not None and workers is not None:
        raise ConfigError("--workers and --scheduler exclude each other (a cluster has workers)")
    count = (os.cpu_count() or 1) if workers is None else int(workers)
    if count < 1:
        raise ConfigError(f"workers must be >= 1, got {count}")
    return count


def _announce(client: Client, where: str, say: Callable[[str], None]) -> tuple[int, str | None]:
    """Say where the runs go (cluster, address, workers, dashboard); (workers, dashboard)."""
    workers = len(client.scheduler_info().get("workers", {}))
    dashboard = _dashboard(client)
    say(
        f"Dask {where} at {client.scheduler.address}, {workers} worker(s); "
        f"dashboard: {dashboard or 'none (pip install bokeh to serve it)'}"
    )
    return workers, dashboard


@contextmanager
def dask_cluster(
    workers: int | None = None, scheduler: str | None = None, quiet: bool = False
) -> Iterator[Client | None]:
    """A Dask client: a ``LocalCluster`` of ``workers`` spawned processes (default
    ``os.cpu_count()``), or the workers of a running ``scheduler``; None with ``workers == 1``
    (every batch in this process). Closed, with its cluster, on exit. :func:`execute_jobs` opens
    one per batch; a caller with several batches (a tuning search) passes one as ``client``.
    Unless ``quiet``, where it runs goes to stderr."""
    count = worker_count(workers, scheduler)
    if scheduler is None and count == 1:
        yield None
        return
    client, cluster = _dask_client(count, scheduler)
    try:
        if not quiet:
            _announce(client, scheduler or "LocalCluster", _stderr)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def write_json(path: Path, doc: Any) -> None:
    """A study's ``results.json``: indented JSON (NaN kept), newline-terminated."""
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1, allow_nan=True)
        fh.write("\n")


def study_cache(
    out: Path, cache: bool = True, cache_dir: str | os.PathLike | None = None
) -> RunCache | None:
    """The run cache of a study written to ``out``: ``cache_dir`` (shared between studies) or
    ``out/cache``; None without ``cache``."""
    if not cache:
        return None
    return RunCache(Path(cache_dir) if cache_dir is not None else out / "cache")
