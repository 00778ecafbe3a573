"""Monte-Carlo campaigns: the independent runs of an experiment as Dask tasks, kept as one tidy table.

An experiment plugs in with one pure, picklable, top-level function

    run_one(config, seed: numpy.random.SeedSequence) -> list[dict]

returning tidy rows ``{"run", "case", "filter", "metric", "value"}`` (plus the experiment's own
``extra_columns``). ``run_campaign`` gives run ``i`` the seed ``SeedSequence(seed).spawn(runs)[i]``,
maps ``run_one`` over the runs, and returns every row sorted by its key columns, so the rows --
and every table and figure made from them -- do not depend on the number of workers or on the
order in which runs finish. Metrics that are wall-clock times (``TIMING_METRICS``) are the one
exception: they are kept in the rows but never in a table that is compared across runs.

Decisions:

* Where the runs go: ``workers >= 1`` starts a local Dask cluster of that many worker *processes*
  with one thread each (OMP/MKL/OpenBLAS/NumExpr thread counts set to 1 in the workers, so W
  workers use W cores); ``scheduler="tcp://host:port"`` uses an existing cluster instead (its
  workers must have abyssal installed; start them with ``--nthreads 1`` and
  ``OMP_NUM_THREADS=1``). ``workers=1`` is still a one-process cluster rather than this process:
  a crash in compiled code then loses one task, not the campaign, exactly as with more workers.
  ``workers=0`` runs in this process (no Dask: for tests, debugging and profiling) through the
  same task function and the same retry rule.
* Failures: every task has ``retries=1`` and the local scheduler ``allowed-failures=1``, so a run
  whose worker dies, or which raises, is tried once more. A run that fails twice is returned in
  ``CampaignResult.failures`` with its seed (entropy and spawn key: rerun it alone with
  ``run_one(config, failure.seed_sequence())``); the others are kept. Callers exit non-zero.
* Seeds inside a run: ``derive(seed, *keys)`` gives a sub-stream without calling ``spawn`` (which
  mutates the SeedSequence: a retried run in the same process would otherwise draw new numbers).
* Resume/merge: the rows are checkpointed to ``csv_path`` (rewritten atomically, at most every
  ``checkpoint_seconds`` and at the end, so the file is always a whole table); ``resume=True``
  reads it and runs only the runs it does not contain. Child ``i`` of ``SeedSequence(seed)`` does
  not depend on how many children are spawned, so ``--runs 20 --resume`` after ``--runs 10`` adds
  runs 10..19 to the same table. A sidecar ``<csv>.meta.json`` records the experiment, seed and
  configuration; resuming with a different one is refused.
* CSV floats are written with ``repr`` (shortest round-trip form), so a table made from a read-back
  CSV is bit-identical to one made from the rows in memory.
* Progress: a tqdm bar on a terminal, plain ``[label] run i/n done`` lines otherwise (logs).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from ..extras import require

TIDY_COLUMNS = ("run", "case", "filter", "metric", "value")
#: metric names that are wall-clock measurements: kept in the rows, never in a compared table
TIMING_METRICS = frozenset({"step_ms", "step_us", "run_seconds"})
#: thread counts of the numerical libraries inside every worker process (one core per worker)
SINGLE_THREAD_ENV = {name: "1" for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                             "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")}

RunOne = Callable[[Any, np.random.SeedSequence], list]


def run_seeds(seed: int, runs: int) -> list[np.random.SeedSequence]:
    """The per-run seeds: children 0..runs-1 of SeedSequence(seed) (child i does not depend on runs)."""
    return np.random.SeedSequence(seed).spawn(runs)


def run_index(seed: np.random.SeedSequence) -> int:
    """The run number of a per-run seed made by ``run_seeds`` (the last entry of its spawn key)."""
    return int(seed.spawn_key[-1])


def derive(seed: np.random.SeedSequence, *keys: int) -> np.random.SeedSequence:
    """A sub-stream of ``seed`` named by keys, without mutating ``seed`` (unlike ``spawn``)."""
    return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + tuple(int(k) for k in keys))


@dataclass(frozen=True)
class RunFailure:
    """A run that failed twice (or whose rows were malformed): reported with its seed, never dropped."""

    run: int
    entropy: int
    spawn_key: tuple
    error: str

    def seed_sequence(self) -> np.random.SeedSequence:
        return np.random.SeedSequence(self.entropy, spawn_key=self.spawn_key)

    def describe(self) -> str:
        last = self.error.strip().splitlines()[-1] if self.error.strip() else "unknown error"
        return f"run {self.run} failed twice (seed: SeedSequence({self.entropy}, spawn_key={self.spawn_key})): {last}"


@dataclass
class CampaignResult:
    rows: list[dict]                      # sorted by the key columns
    columns: tuple[str, ...]
    failures: list[RunFailure] = field(default_factory=list)
    runs_reused: int = 0                  # read back from the CSV (resume)
    runs_done: int = 0                    # run now
    wall_seconds: float = 0.0
    where: str = ""                       # "in-process", "local cluster, 2 workers" or the scheduler address

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def runs(self) -> list[int]:
        return sorted({row["run"] for row in self.rows})


# ---------------------------------------------------------------------------------------------
# rows: validation, order, CSV


def _key(row: dict, columns: Sequence[str]) -> tuple:
    return tuple(row[c] if c == "run" else str(row[c]) for c in columns if c != "value")


def sort_rows(rows: Iterable[dict], columns: Sequence[str] = TIDY_COLUMNS) -> list[dict]:
    """Rows in the campaign's canonical order (run, then the other key columns as text)."""
    return sorted(rows, key=lambda row: _key(row, columns))


def _checked_rows(rows, run: int, columns: Sequence[str]) -> list[dict]:
    if not isinstance(rows, list):
        raise TypeError(f"run_one must return a list of dicts, got {type(rows).__name__}")
    out = []
    for row in rows:
        missing = [c for c in columns if c not in row]
        if missing:
            raise ValueError(f"row {row!r} lacks the column(s) {missing}")
        if int(row["run"]) != run:
            raise ValueError(f"row {row!r} names run {row['run']}, but its seed is run {run}")
        clean = {c: row[c] for c in columns}
        clean["run"] = run
        clean["value"] = float(row["value"])
        out.append(clean)
    return out


def write_csv(path: Path, rows: Sequence[dict], columns: Sequence[str]) -> None:
    """Write the rows atomically (temporary file + rename): the file is always a whole table."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([repr(row[c]) if c == "value" else row[c] for c in columns])
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(buffer.getvalue())
    os.replace(tmp, path)


def read_csv(path: Path, columns: Sequence[str] = TIDY_COLUMNS) -> list[dict]:
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        if tuple(reader.fieldnames or ()) != tuple(columns):
            raise ValueError(f"{path}: columns {reader.fieldnames} differ from this experiment's {list(columns)}")
        return [{**row, "run": int(row["run"]), "value": float(row["value"])} for row in reader]


# ---------------------------------------------------------------------------------------------
# the task


def _limit_threads() -> None:
    """One thread per worker for libraries already loaded (the environment covers later ones)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: the environment variables already did the job at start-up
        return
    threadpool_limits(1)


def run_task(run_one: RunOne, config, seed: np.random.SeedSequence, columns: tuple[str, ...], in_worker: bool = True) -> list[dict]:
    """One run, checked: what every worker executes (and ``workers=0`` calls directly)."""
    if in_worker:
        _limit_threads()
    return _checked_rows(run_one(config, seed), run_index(seed), columns)


# ---------------------------------------------------------------------------------------------
# progress


class _Progress:
    def __init__(self, label: str, total: int, stream=None):
        self.label, self.total, self.done = label, total, 0
        self.stream = stream or sys.stderr
        self.bar = None
        if total and self.stream.isatty():
            tqdm = require("tqdm", "the campaign progress bar").tqdm

            self.bar = tqdm(total=total, desc=label, unit="run", file=self.stream, leave=False)

    def __call__(self, message: str) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(message, refresh=True)
        else:
            print(f"[{self.label}] run {self.done}/{self.total} {message}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ---------------------------------------------------------------------------------------------
# the harness


def _meta(experiment: str, seed: int, config, columns) -> dict:
    return {"experiment": experiment, "seed": int(seed), "config": repr(config), "columns": list(columns)}


def _read_previous(csv_path: Path, meta: dict, columns) -> list[dict]:
    meta_path = csv_path.with_name(csv_path.name + ".meta.json")
    if not csv_path.exists():
        return []
    if meta_path.exists():
        previous = json.loads(meta_path.read_text())
        if previous != meta:
            changed = [k for k in meta if previous.get(k) != meta[k]]
            raise ValueError(f"--resume: {csv_path} was made with a different {', '.join(changed)}; "
                             "use another --out or drop --resume")
    return read_csv(csv_path, columns)


def run_campaign(run_one: RunOne, config, runs: int, seed: int = 0, *, workers: int | None = None,
                 scheduler: str | None = None, csv_path: str | Path | None = None, resume: bool = False,
                 experiment: str = "campaign", extra_columns: Sequence[str] = (), checkpoint_seconds: float = 5.0,
                 progress: bool = True, progress_stream=None) -> CampaignResult:
    """Run ``run_one(config, seed_i)`` for i = 0..runs-1 and return the sorted rows (see the module docstring).

    workers: local worker processes (default: the cores; 0 = in this process); scheduler: address of an
    existing Dask scheduler (then workers is ignored); csv_path: checkpoint/result table; resume: reuse its runs.
    """
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    if workers is not None and workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    columns = tuple(TIDY_COLUMNS[:-1]) + tuple(extra_columns) + ("value",)
    meta = _meta(experiment, seed, config, columns)
    csv_path = Path(csv_path) if csv_path is not None else None
    if resume and csv_path is None:
        raise ValueError("resume needs a csv_path (--out)")
    previous = _read_previous(csv_path, meta, columns) if resume else []
    # finished runs beyond this call's range stay in the table on disk (never deleted by a smaller --runs);
    # the result holds the runs asked for
    beyond = [row for row in previous if row["run"] >= runs]
    previous = [row for row in previous if row["run"] < runs]
    done = {row["run"] for row in previous}
    seeds = run_seeds(seed, runs)
    todo = [s for s in seeds if run_index(s) not in done]
    if csv_path is not None:
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        csv_path.with_name(csv_path.name + ".meta.json").write_text(json.dumps(meta, indent=1))

    rows: list[dict] = list(previous)
    failures: list[RunFailure] = []
    last_write = [time.monotonic()]
    t0 = time.perf_counter()

    def checkpoint(force: bool = False) -> None:
        if csv_path is not None and (force or time.monotonic() - last_write[0] >= checkpoint_seconds):
            write_csv(csv_path, sort_rows(rows + beyond, columns), columns)
            last_write[0] = time.monotonic()

    checkpoint(force=True)  # from now on the CSV holds exactly the rows of this configuration
    progress = _Progress(experiment, len(todo), progress_stream) if progress else _Progress(experiment, 0, io.StringIO())
    if workers is None and scheduler is None:
        workers = os.cpu_count() or 1
    try:
        if not todo:
            where = "nothing to run (all runs in the table)"
        elif scheduler is None and workers == 0:
            where = "in-process"
            for s in todo:
                started = time.perf_counter()
                for attempt in (1, 2):
                    try:
                        rows += run_task(run_one, config, s, columns, in_worker=False)
                        break
                    except Exception:  # noqa: BLE001 -- reported with the seed below
                        if attempt == 2:
                            failures.append(RunFailure(run_index(s), s.entropy, tuple(s.spawn_key), traceback.format_exc()))
                progress(f"(run {run_index(s)}, {time.perf_counter() - started:.1f} s)")
                checkpoint()
        else:
            where = _run_on_dask(run_one, config, todo, columns, workers, scheduler, rows, failures, progress, checkpoint)
    finally:
        progress.close()
        checkpoint(force=True)
    failures.sort(key=lambda f: f.run)
    return CampaignResult(sort_rows(rows, columns), columns, failures, len(done), len(todo) - len(failures),
                          time.perf_counter() - t0, where)


def _run_on_dask(run_one, config, todo, columns, workers, scheduler, rows, failures, progress, checkpoint) -> str:
    dask = require("dask", "a Monte-Carlo campaign on Dask")
    distributed = require("distributed", "a Monte-Carlo campaign on Dask")
    Client, LocalCluster, as_completed = distributed.Client, distributed.LocalCluster, distributed.as_completed

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        if scheduler is not None:
            cluster, where = None, f"scheduler {scheduler}"
            client = Client(scheduler)
        else:
            # loopback only; the scheduler's HTTP routes on a free port (its default, 8787, may be taken)
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, env=dict(SINGLE_THREAD_ENV),
                                   scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
            client, where = Client(cluster), f"local cluster, {workers} worker process(es)"
        try:
            futures = {}
            for s in todo:
                future = client.submit(run_task, run_one, config, s, columns, retries=1, pure=False,
                                       key=f"run-{run_index(s)}-{dask.base.tokenize(s.entropy, os.getpid(), time.time_ns())}")
                futures[future] = s
            for future in as_completed(futures):
                s = futures[future]
                if future.status == "finished":
                    rows += future.result()
                    progress(f"(run {run_index(s)})")
                else:
                    exc = future.exception()
                    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)) if exc else future.status
                    failures.append(RunFailure(run_index(s), s.entropy, tuple(s.spawn_key), tb))
                    progress(f"(run {run_index(s)} FAILED)")
                future.release()
                checkpoint()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return where


def summarise_failures(result: CampaignResult) -> str:
    return "\n".join(f.describe() for f in result.failures)


def mean_over_runs(rows: Iterable[dict], **match) -> float:
    """Mean of the matching rows' values, summed in run order (the rows are sorted): NaN if none."""
    values = [row["value"] for row in rows if all(row.get(k) == v for k, v in match.items())]
    return math.fsum(values) / len(values) if values else math.nan
