"""Run a campaign on Dask distributed: one task per flight, nothing lost, nothing redone.

* **Where**: a local cluster of worker processes (one thread each: a replay is CPU-bound Python) by default,
  ``workers`` of them (default: the core count); or an existing scheduler (``scheduler="tcp://host:8786"``,
  started with ``dask scheduler`` / ``dask worker``, dask-jobqueue or dask-kubernetes). Workers read the bags
  and configs by the paths in the manifest (resolved to absolute paths), so remote workers need the same file
  system.
* **Nothing lost**: a flight whose data cannot be validated is reported (one line naming it) and the others
  complete. A worker that dies mid-task (killed, out of memory) is replaced by its nanny and the scheduler
  reruns its tasks elsewhere (Dask's own resilience; a task that kills three workers in a row is given up as
  ``KilledWorker`` and reported). Unexpected exceptions are retried once (``retries=1``). Every finished
  flight is written to ``DIR/flights/`` at once, so an interrupted campaign keeps what it finished.
* **Nothing redone**: a flight whose results file exists with the same fingerprint (content of the bags and
  the config, :mod:`gap_validation.campaign.fingerprint`) is reused, not submitted.

Then ``campaign.json``, ``campaign.csv`` and ``index.html`` are written from all flights
(:mod:`gap_validation.campaign.results`, :mod:`gap_validation.campaign.index`).
"""
from __future__ import annotations

import contextlib
import logging
import os
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator

from gap_validation.campaign.findings import find_trends, fleet_series
from gap_validation.campaign.fingerprint import flight_fingerprint
from gap_validation.campaign.manifest import Manifest
from gap_validation.campaign.results import (
    FAILED,
    REUSED,
    VALIDATED,
    CampaignOutcome,
    FlightOutcome,
    channel_summary,
    ensure_directory,
    flight_file,
    load_flight_file,
    write_campaign_csv,
    write_campaign_json,
)
from gap_validation.campaign.task import TASK_OPTIONS, validate_flight
from gap_validation.core.config import load_config
from gap_validation.core.errors import ConfigError, DataError, one_line
from gap_validation.report.terminal import write_json

log = logging.getLogger(__name__)

__all__ = ["run_campaign", "dask_client", "TASK_RETRIES", "CONNECT_TIMEOUT_S"]

#: Reruns of a task that raised an unexpected exception (bad data does not raise: it is reported).
TASK_RETRIES = 1
#: Seconds to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 20

ProgressCallback = Callable[[FlightOutcome, int, int], None]


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, quiet: bool = True) -> Iterator:
    """A ``distributed.Client``: connected to ``scheduler``, or to a new local cluster of ``workers``
    processes.

    Local workers are spawned processes that inherit this process' environment (``os.environ``, e.g. the
    ``LD_LIBRARY_PATH`` the ROS 2 wheels set up), one thread each, the HTTP endpoints on a free port. Both are
    closed on exit.
    ``quiet`` hides Dask's own log lines (cluster start, worker restarts) below ERROR.

    Raises
    ------
    ConfigError
        The scheduler cannot be reached (one line naming the address).
    """
    from distributed import Client, LocalCluster

    logger = logging.getLogger("distributed")
    level = logger.level
    if quiet:
        logger.setLevel(logging.ERROR)
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, ValueError) as err:
                raise ConfigError(f"--scheduler {scheduler}: cannot connect ({one_line(err)})") from None
            with client:
                yield client
        else:
            n = workers or os.cpu_count() or 1
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                              silence_logs=logging.ERROR if quiet else logging.INFO) as cluster, \
                    Client(cluster) as client:
                yield client
    finally:
        logger.setLevel(level)


def _check_configs(manifest: Manifest) -> None:
    """Load every config once before any work: a bad one is a usage error (exit 2), not a flight's failure."""
    first = {}
    for i, f in enumerate(manifest.flights):
        first.setdefault(f.config, i)
    for config, i in first.items():
        try:
            load_config(config)
        except ConfigError as err:
            raise ConfigError(f"{manifest.source}: flights[{i}].config: {err}") from None


def _fail(outcome: FlightOutcome, message: str) -> None:
    outcome.status = FAILED
    outcome.errors.append(message)


def _adopt(outcome: FlightOutcome, data: dict, path: Path | None) -> None:
    """Take a flight's results (its replay JSON with the ``campaign`` object) into its outcome."""
    meta = data.get("campaign") or {}
    outcome.results_path = path
    outcome.channels = {
        name: channel_summary(ch) for name, ch in data["channels"].items() if isinstance(ch, dict)
    }
    outcome.errors = list(meta.get("errors") or [])
    outcome.warnings = list(meta.get("warnings") or [])
    outcome.elapsed_s, outcome.cpu_s = meta.get("elapsed_s"), meta.get("cpu_s")
    outcome.worker = meta.get("worker")


def _store(outcome: FlightOutcome, done: dict, out_dir: Path) -> None:
    """Write a finished task's results to ``DIR/flights/`` (atomically) and take them into ``outcome``."""
    if done.get("results") is None:
        outcome.elapsed_s, outcome.cpu_s = done.get("elapsed_s"), done.get("cpu_s")
        outcome.worker = done.get("worker")
        for error in done.get("errors") or ["nothing validated"]:
            _fail(outcome, error)
        return
    data = dict(done["results"])
    data["campaign"] = {
        **outcome.flight.metadata(),
        "fingerprint": outcome.fingerprint,
        "errors": list(done.get("errors") or []),
        "warnings": list(done.get("warnings") or []),
        **{k: done.get(k) for k in ("messages", "elapsed_s", "cpu_s", "worker")},
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    path = flight_file(out_dir, outcome.flight)
    try:
        write_json(data, path)
    except DataError as err:             # the results are kept in memory for this run's files
        _adopt(outcome, data, None)
        outcome.unsaved = data
        outcome.warnings.append(f"{one_line(err)}; the flight will be validated again next time")
    else:
        _adopt(outcome, data, path)
    outcome.status = VALIDATED


def _prepare(manifest: Manifest, out_dir: Path) -> tuple[list[FlightOutcome], list[FlightOutcome]]:
    """Every flight's outcome, and those still to validate: fingerprints, results reused where they match."""
    outcomes, pending = [], []
    for flight in manifest.flights:
        outcome = FlightOutcome(flight)
        outcomes.append(outcome)
        try:
            outcome.fingerprint = flight_fingerprint(flight.bags, flight.config, TASK_OPTIONS)
        except DataError as err:
            _fail(outcome, one_line(err))
            continue
        path = flight_file(out_dir, flight)
        data = load_flight_file(path)
        if data is not None and data["campaign"].get("fingerprint") == outcome.fingerprint:
            _adopt(outcome, data, path)
            outcome.status = REUSED
        else:
            pending.append(outcome)
    return outcomes, pending


def _task_key(outcome: FlightOutcome) -> str:
    return f"gap-validate-flight-{flight_file(Path(), outcome.flight).stem}-{outcome.fingerprint[:16]}"


def _submit_all(
    client, pending: list[FlightOutcome], out_dir: Path, step: Callable[[FlightOutcome], None]
) -> None:
    """One task per flight; results stored as they arrive (any order); a failed task fails only its flight."""
    from distributed import as_completed

    futures = {}
    for outcome in pending:
        future = client.submit(
            validate_flight,
            [str(b) for b in outcome.flight.bags],
            str(outcome.flight.config),
            key=_task_key(outcome),
            retries=TASK_RETRIES,
        )
        futures[future] = outcome
    try:
        for future in as_completed(futures):
            outcome = futures[future]
            if future.status == "finished":
                _store(outcome, future.result(), out_dir)
            else:
                error = future.exception()
                _fail(outcome, f"task failed on the cluster ({type(error).__name__}: {one_line(error)})")
            future.release()
            step(outcome)
    except BaseException:
        client.cancel(list(futures))
        raise


def run_campaign(manifest: Manifest, out_dir: str | os.PathLike, *, scheduler: str | None = None,
                 workers: int | None = None, client=None, progress: ProgressCallback | None = None,
                 warn: Callable[[str], None] | None = None) -> CampaignOutcome:
    """Validate every flight of ``manifest`` on Dask and write ``campaign.json``, ``campaign.csv``,
    ``index.html``.

    Parameters
    ----------
    manifest : Manifest
        From :func:`gap_validation.campaign.manifest.load_manifest`.
    out_dir : path
        Results directory (created); per-flight results in ``out_dir/flights/`` are reused when they match.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); default: a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: the core count).
    client : distributed.Client, optional
        Use this client (and its cluster) instead; it is left open.
    progress : callable, optional
        ``progress(flight_outcome, done, total)`` after each flight (reused ones first).
    warn : callable, optional
        Called with one-line warnings (e.g. no worker connected to the scheduler yet, a figure not drawn).

    Returns
    -------
    CampaignOutcome
        Every flight's outcome (manifest order), the one-line errors (``<flight>: ...``), the trends.

    Raises
    ------
    ConfigError
        A config cannot be loaded, ``out_dir`` cannot be created, the scheduler cannot be reached.
    """
    start = time.perf_counter()
    _check_configs(manifest)
    out_dir = ensure_directory(Path(out_dir))
    outcomes, pending = _prepare(manifest, out_dir)
    total, done = len(outcomes), [0]

    def step(outcome: FlightOutcome) -> None:
        done[0] += 1
        if progress is not None:
            progress(outcome, done[0], total)

    for outcome in outcomes:
        if outcome not in pending:
            step(outcome)
    result = CampaignOutcome(manifest=manifest, out_dir=out_dir, flights=outcomes, scheduler=scheduler)
    if pending:
        quiet = not logging.getLogger().isEnabledFor(logging.DEBUG)
        with (
            contextlib.nullcontext(client)
            if client is not None
            else dask_client(scheduler, workers, quiet) as cl
        ):
            _run_pending(cl, result, pending, step, warn)
    result.errors = [f"{o.flight.name}: {e}" for o in outcomes for e in o.errors]
    result.warnings = [f"{o.flight.name}: {w}" for o in outcomes for w in o.warnings]
    result.findings = find_trends(fleet_series(outcomes))
    _write_files(result, warn)
    result.elapsed_s = time.perf_counter() - start
    return result


def _workers(client) -> set[str]:
    return set(client.scheduler_info(n_workers=-1).get("workers", {}))


def _run_pending(client, result: CampaignOutcome, pending: list[FlightOutcome],
                 step: Callable[[FlightOutcome], None], warn: Callable[[str], None] | None) -> None:
    """Submit the flights still to validate; note the workers, and those lost during the run."""
    result.scheduler = client.scheduler.address
    before = _workers(client)
    result.workers = len(before)
    if not before and warn is not None:
        warn(f"no worker is connected to {result.scheduler} yet: the flights wait for one")
    _submit_all(client, pending, result.out_dir, step)
    result.workers_lost = len(before - _workers(client))


def _write_files(result: CampaignOutcome, warn: Callable[[str], None] | None) -> None:
    """``campaign.json``, ``campaign.csv`` and ``index.html`` (each written whole or not at all)."""
    from gap_validation.campaign.index import write_index  # matplotlib: imported when needed

    result.files["json"] = write_campaign_json(result)
    result.files["csv"] = write_campaign_csv(result)
    result.files["index"] = write_index(result, warn=warn)
