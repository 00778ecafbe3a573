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
* Never a hang: the campaign waits on its futures in slices of WATCH_SECONDS and a watchdog looks at the
  cluster between them. A finished run's rows must arrive within GATHER_SECONDS (a worker that died holding
  them loses them: the run is submitted again); a local cluster with no live worker for NO_WORKER_SECONDS (a
  worker whose restart hangs under load: seen at load 8-23) is replaced by a new one (its worker processes
  killed) and its unfinished runs are submitted again; a run is submitted at most ATTEMPTS times, then
  recorded as failed with its seed; and
  when no run finishes for ``run_timeout`` seconds (default DEFAULT_RUN_TIMEOUT), every unfinished run is
  recorded as failed with its seed. So ``run_campaign`` returns, whatever happens to the workers.
* Ctrl-C (SIGINT): the finished runs are written to the table and ``CampaignInterrupted`` (a
  KeyboardInterrupt) says how many, in one line, for the command to print (``abyssal reproduce`` exits 130;
  ``--resume`` runs the others). Local workers ignore SIGINT (a terminal's Ctrl-C reaches the whole process
  group): the campaign closes them.
* Seeds inside a run: ``derive(seed, *keys)`` gives a sub-stream without calling ``spawn`` (which
  mutates the SeedSequence: a retried run in the same process would otherwise draw new numbers).
* Resume/merge: the rows are checkpointed to ``csv_path`` (rewritten atomically, at most every
  ``checkpoint_seconds`` and at the end, so the file is always a whole table of finished runs);
  ``resume=True`` reads it and runs only the runs it does not contain. Child ``i`` of
  ``SeedSequence(seed)`` does not depend on how many children are spawned, so ``--runs 20 --resume``
  after ``--runs 10`` adds runs 10..19 to the same table, and ``--runs 5 --resume`` keeps runs 5..9
  on disk (the result reports runs 0..4). Nothing is adopted on trust: a sidecar ``<csv>.meta.json``
  (written before the table, both atomically) records the experiment, seed, configuration and columns,
  the sha256 of the table as last written, and for each finished run its row count, the sha256 of its
  rows and a short digest of each row. Resume refuses (``TableRefused``, a ValueError; nothing is run
  or written) a table without a sidecar, a sidecar that is damaged, older or of another experiment,
  configuration or seed, and a table that is not byte for byte the one written (or the one before it,
  when a write was interrupted between the sidecar and the table), naming the file and the first lines
  that differ: a changed or cut value, a duplicated, deleted or foreign row, a run cut short. A run
  counts as done only with all its rows exactly as written. NaN is a value an experiment may write (no
  particle count for a Kalman filter), so finiteness is not required of a row: that the value is the
  one written is.
* CSV floats are written with ``repr`` (shortest round-trip form), so a table made from a read-back
  CSV is bit-identical to one made from the rows in memory.
* Progress: a tqdm bar on a terminal, plain ``[label] run i/n done`` lines otherwise (logs).
"""
from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import os
import signal
import sys
import threading
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

#: seconds between the campaign's looks at its futures and its workers (the watchdog's period)
WATCH_SECONDS = 1.0
#: seconds the rows of a finished run may take to reach the campaign (else its worker died holding them)
GATHER_SECONDS = 30.0
#: seconds a local cluster may have no live worker while runs wait before it is replaced
NO_WORKER_SECONDS = 60.0
#: default seconds a campaign waits while no run finishes before it records the unfinished ones as failed
DEFAULT_RUN_TIMEOUT = 3600.0
#: times a run is submitted in all: again only when its rows were lost with a worker or its cluster was replaced (a
#: run that raises, or kills its worker, is retried once by Dask within one submission, then fails)
ATTEMPTS = 3
#: seconds a cluster and its client may take to close
CLOSE_SECONDS = 20.0
#: run in every local worker process at its start (a preload, in its main thread): a terminal's Ctrl-C goes to the
#: whole process group, and the campaign, not the worker, decides what happens then; a worker that is being closed
#: (the campaign ends or was interrupted) logs nothing (the runs it was given are cancelled, each a warning)
_WORKER_PRELOAD = """
import logging, signal  # abyssal campaign worker
signal.signal(signal.SIGINT, signal.SIG_IGN)


def dask_setup(worker):
    from distributed.core import Status

    closing = {Status.closing, Status.closing_gracefully, Status.closed}

    def open_only(record):
        return worker.status not in closing

    for name in ("distributed", ""):
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(open_only)
"""


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


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a campaign; its finished runs are in the table (the message says how many, in one line)."""


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
    out, seen = [], set()
    for row in rows:
        missing = [c for c in columns if c not in row]
        if missing:
            raise ValueError(f"row {row!r} lacks the column(s) {missing}")
        if int(row["run"]) != run:
            raise ValueError(f"row {row!r} names run {row['run']}, but its seed is run {run}")
        clean = {c: row[c] for c in columns}
        clean["run"] = run
        clean["value"] = float(row["value"])
        key = _key(clean, columns)
        if key in seen:
            raise ValueError(f"run_one returned two rows with the key {key} (one value per run x key)")
        seen.add(key)
        out.append(clean)
    return out


def _line(fields: Sequence) -> str:
    """One row as its CSV line (no line terminator), exactly as the table holds it."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(fields)
    return buffer.getvalue()[:-1]


def _fields(row: dict, columns: Sequence[str]) -> list:
    return [repr(row[c]) if c == "value" else row[c] for c in columns]


def _table_text(rows: Sequence[dict], columns: Sequence[str]) -> str:
    return "".join(_line(line) + "\n" for line in [list(columns)] + [_fields(row, columns) for row in rows])


def _replace(path: Path, text: str) -> None:
    """Write text to path atomically (a temporary file renamed over it): a reader sees the old or the new file."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8", newline="") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def _parse_value(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{where}: value {text!r} is not a number") from None


def _parse_run(text: str, where: str) -> int:
    if not text.isdigit():
        raise ValueError(f"{where}: run {text!r} is not a run number")
    return int(text)


def _parsed_lines(path: Path, text: str, columns: Sequence[str]):
    """(line number, fields) of every data line; the header must be the columns."""
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, None)
    if header is None or tuple(header) != tuple(columns):
        raise ValueError(f"{path}, line 1: columns {header} differ from this experiment's {list(columns)}")
    for fields in reader:
        yield reader.line_num, fields


def read_csv(path: Path, columns: Sequence[str] = TIDY_COLUMNS) -> list[dict]:
    """The rows of a campaign table (run as int, value as float); a malformed line is refused naming it."""
    path = Path(path)
    rows = []
    for number, fields in _parsed_lines(path, path.read_text(encoding="utf-8"), columns):
        where = f"{path}, line {number}"
        if len(fields) != len(columns):
            raise ValueError(f"{where}: {len(fields)} fields where the table has {len(columns)} (a cut or damaged line)")
        row = dict(zip(columns, fields))
        row["run"], row["value"] = _parse_run(row["run"], where), _parse_value(row["value"], where)
        rows.append(row)
    return rows


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


SIDECAR_FORMAT = "abyssal campaign table 2"
#: how many problems a refused table's message lists
_PROBLEMS_SHOWN = 6


class TableRefused(ValueError):
    """--resume found a table it cannot trust (no or another sidecar, or rows changed after they were written)."""


def sidecar_path(csv_path: Path) -> Path:
    return Path(csv_path).with_name(Path(csv_path).name + ".meta.json")


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _digest(line: str) -> str:
    """A short digest of one line: enough to tell which row changed (the run's sha256 is the authority)."""
    return hashlib.blake2b(line.encode("utf-8"), digest_size=6).hexdigest()


def _run_records(lines_by_run: dict[int, list[str]]) -> dict[str, dict]:
    """Per finished run: its row count, the sha256 of its lines and each line's short digest (in table order)."""
    return {str(run): {"rows": len(lines), "sha256": _sha256("\n".join(lines)),
                       "row_digests": " ".join(_digest(line) for line in lines)}
            for run, lines in sorted(lines_by_run.items())}


class _Table:
    """The table on disk and its sidecar ``<csv>.meta.json``.

    The sidecar records the experiment, seed, configuration and columns, the sha256 of the table as last
    written (and of the one before it), and for every finished run its row count, the sha256 of its rows
    and a short digest of each row. Every write puts the sidecar first, then the table (each atomically),
    so after an interruption between the two the table on disk is the one written before: ``resume``
    accepts the table whose sha256 is either of the two, and nothing else.
    """

    def __init__(self, csv_path: Path, meta: dict):
        self.path, self.sidecar, self.meta = Path(csv_path), sidecar_path(csv_path), meta
        self.columns = tuple(meta["columns"])
        self.written_sha256: str | None = None  # the table on disk, when this process knows it

    # ------------------------------------------------------------------ writing
    def write(self, rows: Sequence[dict]) -> None:
        lines_by_run: dict[int, list[str]] = {}
        for row in rows:
            lines_by_run.setdefault(row["run"], []).append(_line(_fields(row, self.columns)))
        text = _table_text(rows, self.columns)
        sha = _sha256(text)
        sidecar = {"format": SIDECAR_FORMAT, **self.meta, "table_sha256": sha,
                   "previous_table_sha256": self.written_sha256, "runs": _run_records(lines_by_run)}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _replace(self.sidecar, json.dumps(sidecar, indent=1) + "\n")
        _replace(self.path, text)
        self.written_sha256 = sha

    # ------------------------------------------------------------------ reading (resume)
    def read(self, check_config: bool = True) -> list[dict]:
        """The rows of the table on disk, after checking it is exactly a table this campaign wrote (of this
        configuration, unless check_config is False: see ``check_resume``)."""
        if not self.path.exists():
            return []
        if not self.sidecar.exists():
            raise TableRefused(f"--resume: {self.path} has no sidecar ({self.sidecar.name}): a table abyssal did not "
                               "write, or one copied without it, is never adopted. Use another --out, or drop --resume "
                               f"to start afresh (that replaces {self.path.name})")
        sidecar = self._read_sidecar()
        compared = ("experiment", "seed", "config", "columns") if check_config else ("experiment", "seed", "columns")
        changed = [k for k in compared if sidecar.get(k) != self.meta[k]]
        if changed:
            raise TableRefused(f"--resume: {self.path} was made with a different {', '.join(changed)} "
                               f"(its sidecar {self.sidecar.name} says experiment {sidecar.get('experiment')!r}, seed "
                               f"{sidecar.get('seed')!r}); use another --out or drop --resume")
        text = self.path.read_text(encoding="utf-8")
        sha = _sha256(text)
        rows, problems = self._check(text, sidecar["runs"])
        if sha not in (sidecar["table_sha256"], sidecar["previous_table_sha256"]) and not problems:
            present = {row["run"] for row in rows}
            problems += [f"run {run}: all {record['rows']} of its rows are missing" for run, record in
                         sidecar["runs"].items() if int(run) not in present]
            problems = problems or ["its bytes differ from the table abyssal wrote (sha256 in the sidecar), though "
                                    "every row matches its run's record: reordered or re-encoded by another program?"]
        if problems:
            shown = "\n  ".join(problems[:_PROBLEMS_SHOWN])
            more = f"\n  ... and {len(problems) - _PROBLEMS_SHOWN} more" if len(problems) > _PROBLEMS_SHOWN else ""
            raise TableRefused(f"--resume: {self.path} is not the table abyssal wrote ({len(problems)} problem(s)); "
                               f"nothing was run or changed:\n  {shown}{more}\nUse another --out, or drop --resume to "
                               f"start afresh (that replaces {self.path.name})")
        self.written_sha256 = sha
        return rows

    def _read_sidecar(self) -> dict:
        try:
            sidecar = json.loads(self.sidecar.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as error:
            raise TableRefused(f"--resume: the sidecar {self.sidecar} of {self.path.name} is damaged ({error}); "
                               f"without it {self.path.name} cannot be checked. Use another --out, or drop --resume "
                               "to start afresh") from None
        if not isinstance(sidecar, dict) or sidecar.get("format") != SIDECAR_FORMAT:
            found = sidecar.get("format") if isinstance(sidecar, dict) else type(sidecar).__name__
            raise TableRefused(f"--resume: the sidecar {self.sidecar} is not a {SIDECAR_FORMAT!r} sidecar (format "
                               f"{found!r}: written by an older abyssal, without the hashes of its rows), so "
                               f"{self.path.name}'s runs cannot be checked. Use another --out, or drop --resume")
        runs = sidecar.get("runs")
        wellformed = isinstance(runs, dict) and all(
            isinstance(r, dict) and isinstance(r.get("rows"), int) and isinstance(r.get("sha256"), str)
            and isinstance(r.get("row_digests"), str) for r in runs.values())
        missing = [k for k in ("table_sha256", "previous_table_sha256", *self.meta) if k not in sidecar]
        if missing or not wellformed:
            raise TableRefused(f"--resume: the sidecar {self.sidecar} is damaged "
                               f"({'missing ' + ', '.join(missing) if missing else 'malformed run records'}); "
                               "use another --out, or drop --resume")
        return sidecar

    def _check(self, text: str, records: dict) -> tuple[list[dict], list[str]]:
        """The rows, and every way the table differs from the recorded runs, in line order (each naming the
        line, the run and the row)."""
        columns, path = self.columns, self.path
        key_columns = [c for c in columns if c != "value"]
        rows: list[dict] = []
        problems: list[tuple[int, str]] = []
        lines_by_run: dict[int, list[tuple[int, str]]] = {}
        foreign: dict[int, list[int]] = {}
        seen: dict[tuple, int] = {}
        try:
            parsed = list(_parsed_lines(path, text, columns))
        except (ValueError, csv.Error) as error:
            return [], [str(error)]
        for number, fields in parsed:
            where = f"line {number}"
            if len(fields) != len(columns):
                problems.append((number, f"{where}: {len(fields)} fields where the table has {len(columns)} "
                                         f"({_line(fields)!r}: a cut or damaged line)"))
                continue
            row = dict(zip(columns, fields))
            try:
                run = _parse_run(row["run"], where)
            except ValueError as error:
                problems.append((number, str(error)))
                continue
            key = tuple(row[c] for c in key_columns)
            where = f"line {number} (run {run}, {', '.join(key[1:])})"
            if str(run) not in records:
                foreign.setdefault(run, []).append(number)
                continue
            if key in seen:
                problems.append((number, f"{where}: duplicates line {seen[key]}"))
                continue
            seen[key] = number
            try:
                row["value"] = _parse_value(row["value"], where)
            except ValueError as error:
                problems.append((number, str(error)))
            row["run"] = run
            rows.append(row)
            lines_by_run.setdefault(run, []).append((number, _line(fields)))
        for run, numbers in foreign.items():
            problems.append((numbers[0], f"line {numbers[0]} (run {run}; {len(numbers)} line(s) in all): run {run} is "
                                         "not a finished run of this table's sidecar (rows of another table?)"))
        for run, numbered in lines_by_run.items():
            problems += self._check_run(run, numbered, records[str(run)])
        return rows, [message for _, message in sorted(problems, key=lambda p: p[0])]

    @staticmethod
    def _check_run(run: int, numbered: list[tuple[int, str]], record: dict) -> list[tuple[int, str]]:
        """How the lines of one run differ from its record (row count, sha256, the digest of each row)."""
        lines = [line for _, line in numbered]
        if len(lines) == record["rows"] and _sha256("\n".join(lines)) == record["sha256"]:
            return []
        expected = record["row_digests"].split()
        digests = [_digest(line) for line in lines]
        for i, (number, line) in enumerate(numbered):
            if i < len(expected) and digests[i] == expected[i]:
                continue
            shown = f"line {number} (run {run}: {line!r})"
            if i + 1 < len(expected) and digests[i] == expected[i + 1]:
                return [(number, f"{shown}: the row of run {run} before it is missing (run {run} has {len(lines)} of "
                                 f"its {record['rows']} rows)")]
            if digests[i] in expected:
                return [(number, f"{shown}: out of place among run {run}'s rows")]
            return [(number, f"{shown}: differs from the row written when run {run} finished (a changed or cut value?)")]
        last = numbered[-1][0]
        if len(lines) < record["rows"]:
            return [(last, f"run {run} has {len(lines)} of its {record['rows']} rows: the rows after line {last} are "
                           "missing (a cut table?)")]
        return [(last, f"run {run}: its rows differ from its record (sha256) though each row matches")]


def _meta(experiment: str, seed: int, config, columns) -> dict:
    return {"experiment": experiment, "seed": int(seed), "config": repr(config), "columns": list(columns)}


def check_resume(csv_path: str | Path, experiment: str, seed: int = 0, extra_columns: Sequence[str] = ()) -> None:
    """Refuse (TableRefused) a table that ``run_campaign(..., resume=True)`` would refuse whatever the
    configuration: for an experiment whose configuration is known only after an expensive preparation (one that
    trains models on its first run), so a bad table is refused before that work. The configuration is checked
    when the campaign starts."""
    columns = tuple(TIDY_COLUMNS[:-1]) + tuple(extra_columns) + ("value",)
    _Table(Path(csv_path), _meta(experiment, seed, None, columns)).read(check_config=False)


def run_campaign(run_one: RunOne, config, runs: int, seed: int = 0, *, workers: int | None = None,
                 scheduler: str | None = None, csv_path: str | Path | None = None, resume: bool = False,
                 experiment: str = "campaign", extra_columns: Sequence[str] = (), checkpoint_seconds: float = 5.0,
                 progress: bool = True, progress_stream=None, run_timeout: float = DEFAULT_RUN_TIMEOUT) -> CampaignResult:
    """Run ``run_one(config, seed_i)`` for i = 0..runs-1 and return the sorted rows (see the module docstring).

    workers: local worker processes (default: the cores; 0 = in this process); scheduler: address of an
    existing Dask scheduler (then workers is ignored); csv_path: checkpoint/result table; resume: reuse its runs;
    run_timeout: seconds without any run finishing after which the unfinished runs are recorded as failed.
    """
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    if workers is not None and workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    if not run_timeout > 0:
        raise ValueError(f"run_timeout must be a positive number of seconds, got {run_timeout!r}")
    columns = tuple(TIDY_COLUMNS[:-1]) + tuple(extra_columns) + ("value",)
    if resume and csv_path is None:
        raise ValueError("resume needs a csv_path (--out)")
    table = _Table(Path(csv_path), _meta(experiment, seed, config, columns)) if csv_path is not None else None
    previous = table.read() if resume else []
    # finished runs beyond this call's range stay in the table on disk (never deleted by a smaller --runs);
    # the result holds the runs asked for
    beyond = [row for row in previous if row["run"] >= runs]
    previous = [row for row in previous if row["run"] < runs]
    done = {row["run"] for row in previous}
    seeds = run_seeds(seed, runs)
    todo = [s for s in seeds if run_index(s) not in done]

    rows: list[dict] = list(previous)
    failures: list[RunFailure] = []
    last_write = [time.monotonic()]
    t0 = time.perf_counter()

    def checkpoint(force: bool = False) -> None:
        if table is not None and (force or time.monotonic() - last_write[0] >= checkpoint_seconds):
            table.write(sort_rows(rows + beyond, columns))
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
            where = _DaskRuns(run_one, config, columns, workers, scheduler, run_timeout, rows, failures, progress,
                              checkpoint).run(todo)
    except KeyboardInterrupt:
        interrupted = True
    else:
        interrupted = False
    finally:
        with _sigint_ignored():  # a second Ctrl-C must not cut the table's last write short
            progress.close()
            checkpoint(force=True)
    if interrupted:
        finished = len({row["run"] for row in rows})
        kept = f"kept in {table.path}" if table is not None else "not kept (no table: give --out)"
        raise CampaignInterrupted(f"interrupted: {finished} finished run(s) of {runs} {kept}"
                                  + ("; --resume runs the others" if table is not None else ""))
    failures.sort(key=lambda f: f.run)
    return CampaignResult(sort_rows(rows, columns), columns, failures, len(done), len(todo) - len(failures),
                          time.perf_counter() - t0, where)


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored inside (in the main thread; elsewhere nothing to do: signals reach the main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _sigint_deferred():
    """Inside, SIGINT sets the flag it yields instead of raising where it lands (in the main thread; elsewhere the
    flag stays unset): the caller raises KeyboardInterrupt between its waits. (Raised inside Dask's client.sync, a
    KeyboardInterrupt makes the event loop log a traceback of distributed's own.)"""
    flag = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: flag.set())
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _quiet(logger: str = "distributed"):
    """Dask's logging silenced (a teardown after Ctrl-C or a lost worker logs tracebacks of cancelled tasks)."""
    log = logging.getLogger(logger)
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


class _DaskRuns:
    """The runs of a campaign on Dask, waited for with a watchdog (the module docstring's "Never a hang")."""

    def __init__(self, run_one, config, columns, workers, scheduler, run_timeout, rows, failures, progress, checkpoint):
        self.run_one, self.config, self.columns = run_one, config, columns
        self.workers, self.scheduler, self.run_timeout = workers, scheduler, run_timeout
        self.rows, self.failures, self.progress, self.checkpoint = rows, failures, progress, checkpoint
        self.dask = require("dask", "a Monte-Carlo campaign on Dask")
        self.distributed = require("distributed", "a Monte-Carlo campaign on Dask")
        self.client = self.cluster = None
        self.pending: dict = {}  # future -> (seed, attempt)
        self.abandoned = False  # runs were given up on: their workers may never answer a close

    # ------------------------------------------------------------------ the cluster
    def _connect(self) -> str:
        Client, LocalCluster = self.distributed.Client, self.distributed.LocalCluster
        if self.scheduler is not None:
            self.client = Client(self.scheduler)
            return f"scheduler {self.scheduler}"
        # loopback only; the scheduler's HTTP routes on a free port (its default, 8787, may be taken)
        preload = [*self.dask.config.get("distributed.worker.preload", []), _WORKER_PRELOAD]
        self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                    dashboard_address=None, env=dict(SINGLE_THREAD_ENV), preload=preload,
                                    scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
        self.client = Client(self.cluster)
        return f"local cluster, {self.workers} worker process(es)"

    def _kill_workers(self, cluster) -> None:
        """SIGKILL to the local cluster's worker processes (one whose start hung never answers a close)."""
        for nanny in list(cluster.workers.values()) if cluster is not None else ():
            pid = getattr(getattr(getattr(nanny, "process", None), "process", None), "pid", None)
            if pid:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)

    def _close(self, kill: bool = False) -> None:
        """Close the client and the local cluster within CLOSE_SECONDS each (kill: its worker processes first); a
        worker process left behind is killed."""
        client, cluster, self.client, self.cluster = self.client, self.cluster, None, None
        with _quiet():
            if kill:
                self._kill_workers(cluster)
            for closing in (client, cluster):
                if closing is None:
                    continue
                try:
                    closing.close(timeout=CLOSE_SECONDS)
                except Exception:  # noqa: BLE001 -- a cluster that cannot close cleanly is killed below
                    pass
            self._kill_workers(cluster)

    def _live_workers(self) -> int:
        try:
            return len(self.client.scheduler_info(n_workers=-1)["workers"])
        except Exception:  # noqa: BLE001 -- a scheduler that does not answer has no worker we can use
            return 0

    # ------------------------------------------------------------------ the runs
    def _submit(self, seed, attempt: int) -> None:
        key = f"run-{run_index(seed)}-{self.dask.base.tokenize(seed.entropy, os.getpid(), time.time_ns())}"
        future = self.client.submit(run_task, self.run_one, self.config, seed, self.columns, retries=1, pure=False,
                                    key=key)
        self.pending[future] = (seed, attempt)

    def _again(self, seed, attempt: int, why: str) -> None:
        """Submit a run once more, or record it as failed with its seed after ATTEMPTS submissions."""
        if attempt < ATTEMPTS:
            self._submit(seed, attempt + 1)
        else:
            self._fail(seed, why)

    def _fail(self, seed, why: str) -> None:
        self.failures.append(RunFailure(run_index(seed), seed.entropy, tuple(seed.spawn_key), why))
        self.progress(f"(run {run_index(seed)} FAILED)")

    def _collect(self, future) -> None:
        seed, attempt = self.pending.pop(future)
        if future.status == "finished" and not self._held(future):
            self._again(seed, attempt, "its rows were lost with its worker")
        elif future.status == "finished":
            try:
                rows = self._gather(future)
            except Exception as error:  # noqa: BLE001 -- the worker holding its rows died (or its rows are bad)
                if isinstance(error, (TimeoutError, self.distributed.CancelledError, OSError)):
                    self._again(seed, attempt, f"its rows were lost with its worker ({type(error).__name__})")
                else:
                    self._fail(seed, "".join(traceback.format_exception(type(error), error, error.__traceback__)))
            else:
                self.rows += rows
                self.progress(f"(run {run_index(seed)})")
        else:
            try:
                exc = future.exception(timeout=GATHER_SECONDS) if future.status == "error" else None
            except Exception as error:  # noqa: BLE001 -- the exception itself could not be fetched
                exc = error
            tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)) if exc else future.status
            self._fail(seed, tb)
        future.release()
        self.checkpoint()

    @staticmethod
    def _gather(future):
        """The rows of a finished run, waited for at most GATHER_SECONDS (TimeoutError after). The wait is a thread's:
        Dask's own result(timeout=...) leaves an orphaned task in its event loop when it times out, whose exception,
        reported when the garbage collector frees it, has broken CPython 3.11's AST compiler in the same process."""
        box: list = []

        def fetch():
            try:
                box.append(("rows", future.result()))
            except BaseException as error:  # noqa: BLE001 -- handed to the caller
                box.append(("error", error))

        fetcher = threading.Thread(target=fetch, name="abyssal-campaign-gather", daemon=True)
        fetcher.start()
        fetcher.join(GATHER_SECONDS)
        if not box:  # still waiting: it ends when the client closes
            raise TimeoutError(f"the rows did not arrive within {GATHER_SECONDS:g} s")
        kind, value = box[0]
        if kind == "error":
            raise value
        return value

    def _held(self, future) -> bool:
        """Whether a live worker holds the rows of a finished run (a gather of rows that died with their worker
        would wait for a recomputation; timed out, it leaves an orphaned task behind in Dask's event loop)."""
        try:
            return bool(self.client.who_has([future]).get(future.key))
        except Exception:  # noqa: BLE001 -- a scheduler that does not answer holds nothing we can gather
            return False

    def _replace_cluster(self) -> None:
        """A new local cluster for the unfinished runs (the old one has no live worker)."""
        waiting = list(self.pending.values())
        self.pending.clear()
        self._close(kill=True)
        self._connect()
        for seed, attempt in waiting:
            self._again(seed, attempt, f"its local cluster lost every worker for {NO_WORKER_SECONDS:g} s")

    def _give_up(self) -> None:
        for future, (seed, _) in list(self.pending.items()):
            with contextlib.suppress(Exception):
                future.cancel()
            self._fail(seed, f"no run finished within run_timeout = {self.run_timeout:g} s ({self._live_workers()} live "
                             "worker(s)): a run that hangs, or workers that never came back")
        self.pending.clear()
        self.abandoned = True

    def run(self, todo) -> str:
        with self.dask.config.set({"distributed.scheduler.allowed-failures": 1}):
            where = self._connect()
            try:
                with _sigint_deferred() as interrupted:
                    self._watch(todo, interrupted)
            finally:
                with _sigint_ignored():  # a second Ctrl-C must not leave worker processes behind
                    # runs still out (Ctrl-C) or given up on: their workers are killed, not asked to finish
                    self._close(kill=bool(self.pending) or self.abandoned)
        return where

    def _watch(self, todo, interrupted: threading.Event) -> None:
        """Submit the runs and wait for them in WATCH_SECONDS slices, the watchdog between them."""
        for seed in todo:
            self._submit(seed, 1)
        last_finish, no_worker_since = time.monotonic(), None
        while self.pending:
            if interrupted.is_set():
                raise KeyboardInterrupt

            try:
                self.distributed.wait(list(self.pending), timeout=WATCH_SECONDS, return_when="FIRST_COMPLETED")
            except (TimeoutError, self.distributed.CancelledError):
                pass  # nothing finished in this slice, or a future was cancelled (collected below)
            done = [future for future in self.pending if future.done()]
            for future in done:
                self._collect(future)
            now = time.monotonic()
            if done:
                last_finish = now
            if not self.pending:
                break
            if self._live_workers():
                no_worker_since = None
            elif no_worker_since is None:
                no_worker_since = now
            elif self.cluster is not None and now - no_worker_since > NO_WORKER_SECONDS:
                self._replace_cluster()
                last_finish, no_worker_since = time.monotonic(), None
            if now - last_finish > self.run_timeout:
                self._give_up()


def summarise_failures(result: CampaignResult) -> str:
    return "\n".join(f.describe() for f in result.failures)


def mean_over_runs(rows: Iterable[dict], **match) -> float:
    """Mean of the matching rows' values, summed in run order (the rows are sorted): NaN if none."""
    values = [row["value"] for row in rows if all(row.get(k) == v for k, v in match.items())]
    return math.fsum(values) / len(values) if values else math.nan
