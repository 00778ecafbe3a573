"""An older commit of abyssal, built once in its own checkout and venv outside the repository, to time beside this
checkout in the same run (bench_particles: the particle filters against commit 1dd3f6b's).

    python_exe, cache, reason = baseline("1dd3f6b")   # (None, None, why) when it cannot be had

The checkout lives at $ABYSSAL_BASELINE_DIR/<commit> (default ~/.cache/abyssal/baselines/<commit>): a clone of this
repository sharing its objects (``git clone --shared``, the repository itself untouched), checked out at the
commit, with a venv (``pip install -e '<checkout>[experiments]'``) and its own compile cache. The first call builds it
(minutes: the package's dependencies are installed from the index pip is configured with); later calls reuse it.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent


def _root() -> Path:
    return Path(os.environ.get("ABYSSAL_BASELINE_DIR", "~/.cache/abyssal/baselines")).expanduser()


def baseline(commit: str, *, build: bool = True) -> tuple[Path | None, Path | None, str]:
    """(its venv's python, its compile cache, "") or (None, None, the reason it is not available)."""
    folder = _root() / commit
    python = folder / ".venv" / "bin" / "python"
    cache = folder / "cache"
    if python.exists() and (folder / ".built").exists():
        return python, cache, ""
    if not build:
        return None, None, f"{folder} is not built"
    if not (REPOSITORY / ".git").exists():
        return None, None, f"{REPOSITORY} is not a git checkout (commit {commit} cannot be checked out)"
    try:
        if not (folder / ".git").exists():
            folder.parent.mkdir(parents=True, exist_ok=True)
            subprocess.run(["git", "clone", "--quiet", "--shared", "--no-checkout", str(REPOSITORY), str(folder)],
                           check=True, capture_output=True, text=True)
        subprocess.run(["git", "-C", str(folder), "checkout", "--quiet", "--detach", commit], check=True,
                       capture_output=True, text=True)
        if not python.exists():
            subprocess.run([sys.executable, "-m", "venv", str(folder / ".venv")], check=True, capture_output=True,
                           text=True)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", "-e", f"{folder}[experiments]"], check=True,
                       capture_output=True, text=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        detail = getattr(exc, "stderr", "") or str(exc)
        return None, None, f"building commit {commit} in {folder} failed: {detail.strip().splitlines()[-1:]}"
    cache.mkdir(exist_ok=True)
    (folder / ".built").write_text(commit + "\n")
    return python, cache, ""


__all__ = ["baseline"]
