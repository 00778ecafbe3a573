"""Instructions per step of a filter under callgrind (valgrind), beside the model's own kernels: the floor a step is
judged against, counted repeatably on a loaded machine.

    counts = per_step([python, "benchmarks/step_times.py", "--steps", "CPF N=100"], steps=10)
    counts -> {"total": ..., "abyssal's C (runtime and model)": ..., "model kernels": ..., "libmvec": ...}
                                                                      # per step, or None (no valgrind)

The command runs twice, with `steps` and 2 `steps` steps appended as its last argument; the difference of the two
runs' totals, divided by `steps`, is a step's count without start-up. "abyssal's C" is every function of the
libraries in abyssal's compile cache (the runtime and the model's library), "model kernels" the generated functions of
the model (``<model>_*_soa``, the structure-of-arrays f and h), "libmvec" the vector sin/cos/exp they call (glibc's
``_ZGV*``). valgrind 3.19 does not decode AVX-512, so the libraries are built for x86-64-v3 (AVX2, FMA) in a cache
of their own (``ABYSSAL_CFLAGS``; the counts are of that build).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

FLAGS = "-O3 -fPIC -fno-semantic-interposition -march=x86-64-v3"
_LINE = re.compile(r"\s*([\d,]+) \(\s*[\d.]+%\)\s+(.+?)(?: \[(.+)\]|$)")


def available() -> bool:
    return shutil.which("valgrind") is not None and shutil.which("callgrind_annotate") is not None


def _counts(command: list[str], env: dict, out: Path) -> dict[str, int]:
    subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", *command], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=3600)
    text = subprocess.run(["callgrind_annotate", "--threshold=100", str(out)], capture_output=True, text=True,
                          check=True).stdout
    counts = {}
    for line in text.splitlines():
        match = _LINE.match(line)
        if match:
            count = int(match.group(1).replace(",", ""))
            counts[match.group(2)] = counts.get(match.group(2), 0) + count
            if match.group(3):  # (and by the object file the function is in)
                key = f"[{match.group(3)}]"
                counts[key] = counts.get(key, 0) + count
    return counts


def per_step(command: list[str], steps: int, cache: str | None = None) -> dict | None:
    """Instructions per step of `command` + [k] (module docstring); None without valgrind."""
    if not available():
        return None
    # PYTHONHASHSEED fixed: the interpreter's start-up (hashing, dict layouts, GC) then counts the same in both runs;
    # with a random seed it differs by ~10^6 instructions, which swamped (even turned negative) a Kalman step's count
    env = dict(os.environ, ABYSSAL_CFLAGS=FLAGS, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONHASHSEED="0")
    env["ABYSSAL_CACHE_DIR"] = cache or str(Path(tempfile.gettempdir()) / "abyssal-cache-x86-64-v3")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([*command, str(1)], env=env, check=True, stdout=subprocess.DEVNULL, timeout=3600)  # (builds)
        a = _counts([*command, str(steps)], env, Path(tmp) / "a.out")
        b = _counts([*command, str(2 * steps)], env, Path(tmp) / "b.out")

    def part(select) -> float:
        return sum(b[k] - a.get(k, 0) for k in b if select(k)) / steps

    cache_dir = env["ABYSSAL_CACHE_DIR"]
    return {"total": part(lambda k: k == "PROGRAM TOTALS"),
            "abyssal's C (runtime and model)": part(lambda k: k.startswith(f"[{cache_dir}")),
            "model kernels": part(lambda k: re.search(r":\w+_soa$", k) is not None and "abyssal" not in k),
            "libmvec": part(lambda k: ":_ZGV" in k)}


__all__ = ["available", "per_step"]
