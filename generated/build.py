"""Compile committed C sources into a shared library, once per key, in a per-user cache.

The cache key is the sha256 of the sources, the flags, the compiler's version line and the
CPU (flags default to -march=native). An entry is a folder holding the library and an
``entry.json`` with the library's sha256; an entry whose library is missing, truncated or
altered is rebuilt, never trusted. Builds take a per-key file lock and publish the folder
with an atomic rename, so two processes never build the same key twice nor see half a file.

Environment:
    ABYSSAL_CFLAGS      compile flags (default: DEFAULT_CFLAGS)
    ABYSSAL_CC / CC     the C compiler (default: cc, then gcc)
    ABYSSAL_CACHE_DIR   cache folder (default: $XDG_CACHE_HOME/abyssal or ~/.cache/abyssal)
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path

DEFAULT_CFLAGS = "-O3 -fPIC -fno-semantic-interposition -march=native"
LINK_FLAGS = ["-shared"]
LIBS = ["-lm"]
# Structure-of-arrays kernels (files *_soa.c): let the loop vectorise with libmvec's sin/cos
# instead of the scalar fused sincos. These flags do not change any IEEE operation.
SOA_FLAGS = ["-fopenmp-simd", "-fno-builtin-sin", "-fno-builtin-cos"]


def _libraries() -> list[str]:
    # libmvec ships with glibc on x86_64; elsewhere the SoA kernels compile without it.
    if platform.machine() == "x86_64" and platform.libc_ver()[0] == "glibc":
        return ["-lmvec", *LIBS]
    return LIBS


def _file_flags(name: str, flags: list[str]) -> list[str]:
    if not name.endswith("_soa.c"):
        return flags
    extra = [] if "-lmvec" in _libraries() else ["-DABYSSAL_NO_LIBMVEC"]
    return [*flags, *SOA_FLAGS, *extra]


class CompilerNotFoundError(RuntimeError):
    """No C compiler could be found to build the generated sources."""


class BuildError(RuntimeError):
    """The C compiler rejected the generated sources."""


def cache_dir() -> Path:
    if os.environ.get("ABYSSAL_CACHE_DIR"):
        return Path(os.environ["ABYSSAL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "abyssal"


def cflags() -> list[str]:
    return shlex.split(os.environ.get("ABYSSAL_CFLAGS", DEFAULT_CFLAGS))


def compiler() -> str:
    wanted = os.environ.get("ABYSSAL_CC") or os.environ.get("CC")
    candidates = [wanted] if wanted else ["cc", "gcc", "clang"]
    for name in candidates:
        path = shutil.which(name)
        if path:
            return path
    raise CompilerNotFoundError(
        f"no C compiler found (looked for {', '.join(candidates)} on PATH); abyssal compiles its generated C "
        "on first use: install gcc (e.g. `apt-get install gcc`) or set ABYSSAL_CC to a compiler"
    )


@lru_cache(maxsize=8)
def _compiler_identity(cc: str) -> str:
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30, check=False)
    except OSError as exc:
        raise CompilerNotFoundError(f"C compiler {cc!r} cannot be run: {exc}") from exc
    return out.stdout.splitlines()[0] if out.stdout else cc


@lru_cache(maxsize=1)
def _cpu_identity() -> str:
    ident = platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith(("model name", "flags", "Features")):
                    ident += "|" + line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ident


def cache_key(sources: dict[str, str], flags: list[str], cc: str) -> str:
    h = hashlib.sha256()
    for name in sorted(sources):
        h.update(name.encode() + b"\0" + sources[name].encode() + b"\0")
    h.update(" ".join(flags + SOA_FLAGS + _libraries()).encode() + b"\0" + _compiler_identity(cc).encode() + b"\0" + _cpu_identity().encode())
    return h.hexdigest()


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _valid_entry(entry: Path, lib_name: str) -> Path | None:
    lib = entry / lib_name
    meta = entry / "entry.json"
    try:
        recorded = json.loads(meta.read_text())["sha256"]
        if lib.is_file() and _sha256_file(lib) == recorded:
            return lib
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def _compile(sources: dict[str, str], workdir: Path, lib_path: Path, flags: list[str], cc: str) -> None:
    objects = []
    commands = []
    for name, text in sorted(sources.items()):
        src = workdir / name
        src.write_text(text)
        obj = workdir / (name + ".o")
        objects.append(obj)
        commands.append([cc, *_file_flags(name, flags), "-c", str(src), "-o", str(obj)])

    def run(cmd):
        return subprocess.run(cmd, capture_output=True, text=True, check=False)

    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
        results = list(pool.map(run, commands))
    results.append(run([cc, *flags, *LINK_FLAGS, *map(str, objects), "-o", str(lib_path), *_libraries()]))
    for cmd, res in zip(commands + [["link"]], results):
        if res.returncode != 0:
            raise BuildError(f"compiling generated C failed: {' '.join(cmd)}\n{res.stderr[-4000:]}")


def build(model: str, sources: dict[str, str]) -> Path:
    """Path of the compiled library of `sources`, building it if no valid cache entry exists."""
    cc = compiler()
    flags = cflags()
    key = cache_key(sources, flags, cc)
    root = cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    entry = root / f"{model}-{key[:24]}"
    lib_name = f"lib{model}.so"
    lib = _valid_entry(entry, lib_name)
    if lib:
        return lib
    with open(root / f"{model}-{key[:24]}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        lib = _valid_entry(entry, lib_name)  # another process may have built it while we waited
        if lib:
            return lib
        work = Path(tempfile.mkdtemp(prefix=f".{model}-", dir=root))
        try:
            _compile(sources, work, work / lib_name, flags, cc)
            meta = {"sha256": _sha256_file(work / lib_name), "key": key, "flags": flags, "compiler": _compiler_identity(cc)}
            (work / "entry.json").write_text(json.dumps(meta, indent=1))
            if entry.exists():
                shutil.rmtree(entry)  # corrupted entry: replaced, not trusted
            os.replace(work, entry)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    lib = _valid_entry(entry, lib_name)
    if lib is None:
        raise BuildError(f"cache entry {entry} is not valid right after building it")
    return lib
