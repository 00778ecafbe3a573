"""Where a campaign's numbers came from: the command, the code's commit, the machine and its load.

``started(command, workers)`` is taken when `abyssal reproduce` starts and ``finished(record, wall_seconds)`` when
it ends; the record goes into <out>/<name>.json ("provenance") and from there into every generated block of the
docs (publish.py), so a table in the docs names the command that made it, the commit it ran and the CPU and load
it ran under.

* command: the canonical `abyssal reproduce NAME ...` line, with only what changes the numbers (--quick, --runs,
  --seed, --particles); --workers and --scheduler never do (campaign.py), so they are recorded apart.
* commit: ``git rev-parse HEAD`` of the checkout the package runs from, with ``dirty`` true when tracked files
  differ from it (the numbers then came from uncommitted code); None outside a git checkout (an installed wheel).
* cpu: the model name of /proc/cpuinfo (platform.processor() elsewhere), the logical cores, and the 1-minute load
  average at the start and the end.
"""
from __future__ import annotations

import os
import platform
import subprocess
import time
from pathlib import Path

#: the source checkout (runtime/experiments/ -> the repository root)
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def reproduce_command(name: str, *, runs: int, seed: int, quick: bool = False, particles: int | None = None) -> str:
    """The canonical command of a campaign (module docstring)."""
    parts = ["abyssal reproduce", name] + (["--quick"] if quick else []) + [f"--runs {runs}", f"--seed {seed}"]
    if particles is not None:
        parts.append(f"--particles {particles}")
    return " ".join(parts)


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(SOURCE_ROOT), *args], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def code_version() -> dict:
    """{"commit": full hash or None, "dirty": tracked files differ from it (None outside git)}."""
    commit = _git("rev-parse", "HEAD")
    if commit is None:
        return {"commit": None, "dirty": None}
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status) if status is not None else None}


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load() -> float | None:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def started(command: str, workers: int | None = None, scheduler: str | None = None) -> dict:
    """The record at the start of a campaign (module docstring)."""
    return {"command": command, **code_version(), "cpu": cpu_model(), "cores": os.cpu_count(),
            "workers": workers, "scheduler": scheduler, "load_start": _load(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S %z")}


def finished(record: dict, wall_seconds: float) -> dict:
    """The record completed at the end: the load then and the wall time."""
    return {**record, "load_end": _load(), "wall_seconds": round(float(wall_seconds), 1)}


def resumed(record: dict, earlier: dict | None) -> dict:
    """The record of a campaign resumed (--resume) from a table that an earlier session (`earlier`: its record, or
    None) began: this session's record with every earlier session's in "earlier_sessions", oldest first, so that
    the blocks name every commit, load and wall time behind the table, not only the resume's."""
    if not earlier:
        return record
    sessions = [*earlier.get("earlier_sessions", []), {k: v for k, v in earlier.items() if k != "earlier_sessions"}]
    return {**record, "earlier_sessions": sessions}


def describe(record: dict) -> str:
    """One line for a generated block: "`command` at commit abc1234 (dirty), CPU, load a-b, wall"; a resumed
    campaign's line covers every session (its commits, the loads' range, the walls' sum)."""
    sessions = [*record.get("earlier_sessions", []), record]
    codes = []
    for session in sessions:
        commit = session.get("commit")
        code = (f"{commit[:10]}" + (" (uncommitted changes)" if session.get("dirty") else "")) if commit else "no git commit"
        if code not in codes:
            codes.append(code)
    code = codes[0] if codes == ["no git commit"] else ("commit " if len(codes) == 1 else "commits ") + ", ".join(codes)
    loads = [v for s in sessions for v in (s.get("load_start"), s.get("load_end")) if v is not None]
    load = f"load {min(loads):.1f}-{max(loads):.1f}" if loads else "load unknown"
    workers = record.get("workers")
    where = f"--workers {workers}" if workers is not None else (record.get("scheduler") or "default workers")
    walls = [s.get("wall_seconds") for s in sessions]
    wall = sum(walls) if all(w is not None for w in walls) else None
    wall_text = f"{wall / 60:.0f} min wall" if wall and wall >= 120 else (f"{wall:.0f} s wall" if wall else "")
    if wall_text and len(sessions) > 1:
        wall_text += f" in {len(sessions)} sessions (--resume)"
    return (f"`{record.get('command')}` at {code}; {record.get('cpu')}, {record.get('cores')} cores, {where}, {load}"
            + (f", {wall_text}" if wall_text else ""))
