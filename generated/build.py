"""Compile generated C into a shared library, once per key, in a bounded per-user cache.

Key. The sha256 of the sources, the compile flags, the libraries, the compiler *as requested*
(the text of ABYSSAL_CC or CC, or "default") and the target: the CPU model and feature flags when
the flags say ``native`` (the default ``-march=native``), else only the machine architecture.
Nothing in the key needs the compiler to be present or run, so a valid entry is used on a machine
without a compiler (a vehicle computer). The compiler's resolved path and ``--version`` line are
recorded in the entry (bounded by VERSION_TIMEOUT; a hanging ``--version`` costs seconds and
records "unknown"), not keyed: upgrading gcc in place does not rebuild (``abyssal cache clear``
does); choosing another compiler through ABYSSAL_CC does.

Entry. ``<cache>/<model>-<key[:24]>/`` holds ``lib<model>.so``, ``entry.json`` (format, the full
key, the library's sha256, flags, target, compiler) and ``last_used`` (its mtime is the last load;
a process that uses the library holds a shared flock on it until it exits). An entry that is not
exactly that (a file in its place, a missing or altered library, missing or foreign entry.json)
is rebuilt, never trusted.

Writes are atomic. A build compiles in a temporary folder ``.<model>-*``, loads the library with
ctypes and smoke-calls it (every exported CasADi symbol resolves, each ``*_n_in``/``*_n_out``
returns what the source says), and only then renames the folder into place; a replaced or
evicted entry is renamed away before it is deleted. Abyssal never writes into a published
library, so a process that has it mapped never sees it change (unlinking a mapped library is
safe; truncating or rewriting it in place kills that process with SIGBUS: never edit entries
by hand, delete them or use ``abyssal cache clear``).

Visible. A build running longer than PROGRESS_AFTER seconds prints one line on stderr, "abyssal:
compiling <model>: <k> files, <size> MB of C ..." and " done in <t> s" at its end; a timed-out build
names the files still compiling.

Builds of one key are serialised by ``<model>-<key[:24]>.lock`` (flock, removed after the build).
The compiler runs in its own process group under a deadline (ABYSSAL_BUILD_TIMEOUT): on timeout
the whole group is killed, the temporary folder removed, the lock released, and BuildError raised.

Bounded: after each build, least-recently-used entries are evicted until the cache is under
ABYSSAL_CACHE_MAX_BYTES; an entry in use by any process (its shared flock) is never evicted.

Environment (every error names the variable):
    ABYSSAL_CFLAGS           compile flags (default: DEFAULT_CFLAGS), split like a shell would
    ABYSSAL_CC / CC          the C compiler: a name on PATH or a path (default: cc, then gcc, clang)
    ABYSSAL_CACHE_DIR        cache folder (default: $XDG_CACHE_HOME/abyssal or ~/.cache/abyssal)
    ABYSSAL_BUILD_TIMEOUT    seconds one build may take (default: DEFAULT_TIMEOUT)
    ABYSSAL_CACHE_MAX_BYTES  size cap, bytes or with a K/M/G suffix (powers of 1024; default 1G)
"""
from __future__ import annotations

import ctypes
import errno
import fcntl
import hashlib
import json
import os
import platform
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

# -ffp-contract=off: no a * b + c fused into an FMA (GCC's default in its GNU modes wherever -march=native has FMA);
# the exported CMake project compiles with the same rule, so another -march or build type changes its results only
# through the SoA kernel's sin/cos (libmvec's variant; abyssal/export.py has the measurements)
DEFAULT_CFLAGS = "-O3 -fPIC -fno-semantic-interposition -march=native -ffp-contract=off"
LINK_FLAGS = ["-shared"]
LIBS = ["-lm"]
# Structure-of-arrays kernels (files *_soa.c): let the loop vectorise with libmvec's sin/cos/tan instead of the
# scalar fused sincos, and sqrt without the errno branch (errno is never read).
# -fno-trapping-math: nothing reads the floating-point exception flags, and without it gcc 12 keeps a loop with a
# comparison and a call (a sinc select such as tan3dof's f) scalar where there are no AVX-512 masks (AVX2: 8x slower).
# These flags do not change any IEEE operation.
SOA_FLAGS = ["-fopenmp-simd", "-DABYSSAL_OPENMP_SIMD", "-fno-builtin-sin", "-fno-builtin-cos", "-fno-builtin-tan",
             "-fno-math-errno", "-fno-trapping-math"]
# CasADi's straight-line model code (files *_model.c): gcc's partial-redundancy elimination and code hoisting take
# 20-30 % of its compile time on the larger models and gain no step time (benchmarks/README.md, "Compile flags per
# file kind"). They compute the same values: with contraction off (DEFAULT_CFLAGS) results are bit-identical (with
# contraction on, where gcc fuses a*b+c depends on the expressions they leave: chain24 moved by 7e-17). gcc only.
STRAIGHT_LINE_GCC_FLAGS = ["-fno-tree-pre", "-fno-code-hoisting"]
#: hand-written C (the runtime of abyssal.runtime.compiled) compiles strictly: build(..., strict=True)
STRICT_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]

#: seconds one build may take (all compile and link steps; a slow vehicle computer needs minutes for the largest model)
DEFAULT_TIMEOUT = 600.0
#: a build running longer than this many seconds prints one progress line on stderr (_Progress)
PROGRESS_AFTER = 2.0
#: seconds `cc --version` may take (only run when building, to record the compiler in entry.json)
VERSION_TIMEOUT = 3.0
#: seconds a process waits for another's build of the same key beyond ABYSSAL_BUILD_TIMEOUT
LOCK_MARGIN = 10.0
#: default cap of the cache's total size
DEFAULT_MAX_BYTES = 1 << 30
ENTRY_FORMAT = 2
MARKER = "last_used"
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _libraries() -> list[str]:
    # libmvec ships with glibc on x86_64; elsewhere the SoA kernels compile without it.
    if platform.machine() == "x86_64" and platform.libc_ver()[0] == "glibc":
        return ["-lmvec", *LIBS]
    return LIBS


def _file_flags(name: str, flags: list[str], strict: bool, gcc: bool = False) -> list[str]:
    extra = STRICT_FLAGS if strict else []
    if name.endswith("_model.c") and gcc:
        return [*flags, *STRAIGHT_LINE_GCC_FLAGS, *extra]
    if not name.endswith("_soa.c"):
        return [*flags, *extra]
    vector_math = [] if "-lmvec" in _libraries() else ["-DABYSSAL_NO_LIBMVEC"]
    return [*flags, *SOA_FLAGS, *vector_math, *extra]



class CompilerNotFoundError(RuntimeError):
    """No C compiler could be found to build the generated sources (and no cached library exists)."""


class BuildError(RuntimeError):
    """Building failed: the compiler rejected the sources, timed out, or produced an unusable library."""


class CacheError(RuntimeError):
    """The cache folder cannot be used (named with the variable that chose it)."""


# ------------------------------------------------------------------------------------ environment
def _env(name: str) -> str | None:
    value = os.environ.get(name)
    return value if value else None


def cache_dir() -> Path:
    """The cache folder (not created here)."""
    value = _env("ABYSSAL_CACHE_DIR")
    if value is None:
        base = _env("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return Path(base) / "abyssal"
    folder = Path(value).expanduser()
    if folder.exists() and not folder.is_dir():
        raise CacheError(f"ABYSSAL_CACHE_DIR={value!r} is not a folder")
    return folder.absolute()


def _describe_root(root: Path) -> str:
    if _env("ABYSSAL_CACHE_DIR"):
        return f"ABYSSAL_CACHE_DIR={os.environ['ABYSSAL_CACHE_DIR']!r}"
    return f"the cache folder {root} (set ABYSSAL_CACHE_DIR to use another)"


def _ensure_root(root: Path) -> None:
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CacheError(f"{_describe_root(root)} cannot be created: {exc}") from exc


def cflags() -> list[str]:
    value = os.environ.get("ABYSSAL_CFLAGS")
    if value is None:
        return shlex.split(DEFAULT_CFLAGS)
    try:
        return shlex.split(value)
    except ValueError as exc:
        raise ValueError(f"ABYSSAL_CFLAGS={value!r} cannot be split into flags: {exc}") from None


def _requested_compiler() -> tuple[str | None, str]:
    """(variable, value) of the compiler asked for; (None, "default") when neither is set."""
    for var in ("ABYSSAL_CC", "CC"):
        if _env(var):
            return var, os.environ[var]
    return None, "default"


def compiler() -> str:
    """Absolute path of the C compiler to run."""
    var, wanted = _requested_compiler()
    candidates = [wanted] if var else ["cc", "gcc", "clang"]
    for name in candidates:
        path = shutil.which(name)
        if path:
            return path
    if var:
        raise CompilerNotFoundError(f"{var}={wanted!r} is not an executable (a compiler name on PATH or a path)")
    raise CompilerNotFoundError(
        f"no C compiler found (looked for {', '.join(candidates)} on PATH); abyssal compiles its generated C "
        "on first use: install gcc (e.g. `apt-get install gcc`) or set ABYSSAL_CC to a compiler"
    )


def build_timeout() -> float:
    value = _env("ABYSSAL_BUILD_TIMEOUT")
    if value is None:
        return DEFAULT_TIMEOUT
    try:
        seconds = float(value)
    except ValueError:
        seconds = float("nan")
    if not (seconds > 0 and seconds != float("inf")):
        raise ValueError(f"ABYSSAL_BUILD_TIMEOUT={value!r} must be a positive number of seconds")
    return seconds


_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def max_bytes() -> int:
    value = _env("ABYSSAL_CACHE_MAX_BYTES")
    if value is None:
        return DEFAULT_MAX_BYTES
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([KMGT]?)(?:i?B)?\s*", value, re.IGNORECASE)
    if not match:
        raise ValueError(f"ABYSSAL_CACHE_MAX_BYTES={value!r} must be a size in bytes, e.g. 1073741824, 500M or 2G")
    return int(float(match.group(1)) * _UNITS[match.group(2).upper()])


# ------------------------------------------------------------------------------------ key
@lru_cache(maxsize=1)
def _cpu_identity() -> str:
    ident = platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith(("model name", "flags", "Features", "CPU part")):
                    ident += "|" + line.split(":", 1)[1].strip()
                    if line.startswith(("flags", "Features")):
                        break  # the first processor's lines identify the model
    except OSError:
        pass
    return ident


def target_identity(flags: list[str]) -> str:
    """What the library is built for: the exact CPU for ``native`` flags, else the architecture."""
    if any("native" in flag for flag in flags):
        return _cpu_identity()
    return platform.machine()


def cache_key(sources: dict[str, str], flags: list[str], requested_compiler: str | None = None, strict: bool = False) -> str:
    """The entry key; computable without a compiler (see the module docstring)."""
    if requested_compiler is None:
        requested_compiler = _requested_compiler()[1]
    h = hashlib.sha256()
    for name in sorted(sources):
        h.update(name.encode() + b"\0" + sources[name].encode() + b"\0")
    compiled = flags + SOA_FLAGS + STRAIGHT_LINE_GCC_FLAGS + (STRICT_FLAGS if strict else []) + LINK_FLAGS + _libraries()
    for part in (" ".join(compiled), requested_compiler, target_identity(flags)):
        h.update(part.encode() + b"\0")
    return h.hexdigest()


# ------------------------------------------------------------------------------------ processes
def _kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the process group of `proc` (the compiler and anything it started) and reap `proc`."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def _is_gcc(cc: str) -> bool:
    """Is cc GNU's C compiler ("gcc (Debian 12.2.0-14) 12.2.0", "cc (...) ..."; not clang, which cc may be)?"""
    identity = _compiler_identity(cc).lower()
    return "clang" not in identity and re.match(r"\S*cc(-\d+)? \(", identity) is not None


@lru_cache(maxsize=8)
def _compiler_identity(cc: str) -> str:
    """First line of `cc --version`, at most VERSION_TIMEOUT seconds; "unknown (...)" otherwise."""
    try:
        proc = subprocess.Popen([cc, "--version"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError as exc:
        return f"unknown ({exc})"
    try:
        out, _ = proc.communicate(timeout=VERSION_TIMEOUT)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        proc.stdout.close()
        return f"unknown (`{cc} --version` did not answer within {VERSION_TIMEOUT:g} s)"
    lines = out.decode(errors="replace").splitlines()
    return lines[0].strip() if lines and lines[0].strip() else f"unknown (`{cc} --version` printed nothing)"


@dataclass
class _Job:
    cmd: list[str]
    log: Path
    source: str = "the link step"
    proc: subprocess.Popen | None = None


class _Progress:
    """One line on stderr for a build that takes longer than PROGRESS_AFTER seconds.

    "abyssal: compiling rov4dof: 6 files, 0.97 MB of C ..." once the build has run that long, and
    " done in 12.3 s" (or " failed after ...") at its end; a quick build prints nothing.
    """

    def __init__(self, model: str, sources: dict[str, str]):
        c_files = [text for name, text in sources.items() if name.endswith(".c")]
        megabytes = sum(len(text.encode()) for text in c_files) / 1e6
        self.message = f"abyssal: compiling {model}: {len(c_files)} files, {megabytes:.2f} MB of C ..."
        self.start = time.monotonic()
        self.shown = False
        self._lock = threading.Lock()
        self._timer = threading.Timer(PROGRESS_AFTER, self._show)
        self._timer.daemon = True

    def _show(self):
        with self._lock:
            if not self.shown:
                sys.stderr.write(self.message)
                sys.stderr.flush()
                self.shown = True

    def __enter__(self):
        self._timer.start()
        return self

    def __exit__(self, exc_type, exc, tb):
        self._timer.cancel()
        with self._lock:
            if self.shown:
                outcome = "done in" if exc_type is None else "failed after"
                sys.stderr.write(f" {outcome} {time.monotonic() - self.start:.1f} s\n")
                sys.stderr.flush()
            self.shown = True  # a timer that fires late prints nothing


def _run_jobs(jobs: list[_Job], deadline: float, timeout: float, workdir: Path, max_parallel: int) -> None:
    """Run the commands, at most `max_parallel` at once, each in its own process group.

    Raises BuildError on the first failure or at the deadline; every process group still
    running is killed before returning or raising.
    """
    pending, running = list(jobs), []
    try:
        while pending or running:
            while pending and len(running) < max_parallel:
                job = pending.pop(0)
                with open(job.log, "wb") as log:
                    try:
                        job.proc = subprocess.Popen(job.cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                                    cwd=workdir, start_new_session=True)
                    except OSError as exc:
                        raise BuildError(f"cannot run the C compiler: {' '.join(job.cmd)}: {exc}") from exc
                running.append(job)
            for job in list(running):
                code = job.proc.poll()
                if code is None:
                    continue
                running.remove(job)
                if code != 0:
                    output = job.log.read_text(errors="replace")[-4000:]
                    raise BuildError(f"compiling generated C failed (exit {code}): {' '.join(job.cmd)}\n{output}")
            if running and time.monotonic() > deadline:
                still = ", ".join(job.source for job in running)
                raise BuildError(
                    f"the C compiler did not finish within {timeout:g} s (ABYSSAL_BUILD_TIMEOUT) and was stopped "
                    f"while compiling {still}; nothing was cached: {' '.join(running[0].cmd)}")
            if running:
                time.sleep(0.01)
    finally:
        for job in running:
            _kill_group(job.proc)


def _compile(sources: dict[str, str], workdir: Path, lib_path: Path, flags: list[str], cc: str,
             deadline: float, timeout: float, strict: bool) -> None:
    objects, jobs = [], []
    for name, text in sorted(sources.items()):
        (workdir / name).write_text(text)
    gcc = _is_gcc(cc)
    # largest first: the longest compile starts at once and the others fill the remaining cores
    for name in sorted((n for n in sources if n.endswith(".c")), key=lambda n: (-len(sources[n]), n)):
        src = workdir / name
        obj = workdir / (name + ".o")
        objects.append(obj)
        jobs.append(_Job([cc, *_file_flags(name, flags, strict, gcc), "-c", str(src), "-o", str(obj)], workdir / (name + ".log"), name))
    _run_jobs(jobs, deadline, timeout, workdir, max(1, os.cpu_count() or 1))
    link = _Job([cc, *flags, *LINK_FLAGS, *map(str, objects), "-o", str(lib_path), *_libraries()], workdir / "link.log")
    _run_jobs([link], deadline, timeout, workdir, 1)


# ------------------------------------------------------------------------------------ smoke test
_EXPORT = re.compile(r"^CASADI_SYMBOL_EXPORT\s+(?:const\s+)?\w+[\s*]+(\w+)\s*\(", re.MULTILINE)
_COUNT = re.compile(r"^CASADI_SYMBOL_EXPORT\s+casadi_int\s+(\w+_n_(?:in|out))\s*\(\s*void\s*\)\s*\{\s*return\s+(\d+)\s*;\s*\}", re.MULTILINE)


def smoke_test(lib: Path, sources: dict[str, str], symbols=()) -> None:
    """Load `lib` with ctypes and call into it; BuildError if it is not the library of `sources`.

    Every CasADi-exported symbol of the sources (and every name in `symbols`) must resolve, and
    each ``NAME_n_in`` / ``NAME_n_out`` must return the count written in the source.
    """
    try:
        cdll = ctypes.CDLL(str(lib))
    except OSError as exc:
        raise BuildError(f"the compiler produced a library that cannot be loaded ({exc}); nothing was cached") from None
    text = "\n".join(sources.values())
    for name in sorted(set(_EXPORT.findall(text)) | set(symbols)):
        if not hasattr(cdll, name):
            raise BuildError(f"the compiled library lacks the symbol {name!r} of its sources; nothing was cached")
    for name, expected in _COUNT.findall(text):
        fn = getattr(cdll, name)
        fn.restype, fn.argtypes = ctypes.c_longlong, []
        got = fn()
        if got != int(expected):
            raise BuildError(f"the compiled library's {name}() returned {got}, its source says {expected}; nothing was cached")


# ------------------------------------------------------------------------------------ entries
def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _valid_entry(entry: Path, lib_name: str, key: str) -> Path | None:
    """The entry's library if the entry is exactly what build() publishes for `key`, else None."""
    lib = entry / lib_name
    try:
        if entry.is_symlink() or not entry.is_dir() or lib.is_symlink() or not lib.is_file():
            return None
        meta = json.loads((entry / "entry.json").read_text())
        if meta.get("format") != ENTRY_FORMAT or meta.get("key") != key:
            return None
        if lib.stat().st_size == meta.get("bytes") and _sha256_file(lib) == meta["sha256"]:
            return lib
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    return None


#: entry folder -> file descriptor holding a shared flock on its marker while this process uses it
_IN_USE: dict[Path, int] = {}
_IN_USE_LOCK = threading.Lock()


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _claim(entry: Path) -> bool:
    """Mark the entry as used by this process (shared flock on its marker) and touch its access time.

    False if the entry was evicted or replaced meanwhile. A read-only cache (a deployed copy) is
    used without either: nothing evicts from it.
    """
    with _IN_USE_LOCK:
        return _claim_locked(entry)


def _claim_locked(entry: Path) -> bool:
    marker = entry / MARKER
    held = _IN_USE.get(entry)
    if held is None or not _same_file(held, marker):
        try:
            fd = os.open(marker, os.O_RDONLY | os.O_CREAT, 0o644)
        except OSError:
            return entry.is_dir()  # a read-only cache without markers: nothing can evict from it
        fcntl.flock(fd, fcntl.LOCK_SH)  # an evictor holds LOCK_EX only while renaming the entry away
        if not _same_file(fd, marker):
            os.close(fd)
            return False
        if held is not None:
            os.close(held)  # the entry was rebuilt: hold the new marker
        _IN_USE[entry] = fd
    try:
        os.utime(marker)
    except OSError:
        pass
    return True


class _KeyLock:
    """Exclusive per-key build lock: ``<root>/<name>.lock``, removed by its holder on release.

    After locking, the holder checks that the path still names the file it locked (a previous
    holder may have removed it), so removing the lock file is safe.
    """

    def __init__(self, path: Path, wait: float):
        self.path, self.wait, self.fd = path, wait, None

    def __enter__(self):
        deadline = time.monotonic() + self.wait
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        os.close(fd)
                        raise BuildError(
                            f"another process has held {self.path} for more than {self.wait:g} s while building this "
                            "library (ABYSSAL_BUILD_TIMEOUT); it should give up by itself: try again") from None
                    time.sleep(0.05)
            if _same_file(fd, self.path):
                self.fd = fd
                return self
            os.close(fd)

    def __exit__(self, *exc):
        try:
            os.unlink(self.path)
        except OSError:
            pass
        os.close(self.fd)


def _remove(path: Path, root: Path) -> None:
    """Rename `path` (file or folder) away inside `root`, then delete it: it vanishes atomically."""
    trash = Path(tempfile.mkdtemp(prefix=".trash-", dir=root))
    try:
        os.rename(path, trash / "x")
    except FileNotFoundError:
        pass
    shutil.rmtree(trash, ignore_errors=True)


def _near_misses(root: Path, model: str) -> str:
    """What the cache holds for `model` (to explain a miss on a machine without a compiler)."""
    rows = []
    for meta_path in sorted(root.glob(f"{model}-*/entry.json")) if root.is_dir() else []:
        try:
            meta = json.loads(meta_path.read_text())
            rows.append(f"flags {' '.join(meta['flags'])!r}, compiler {meta['compiler']['requested']!r}, "
                        f"target {meta['target'][:60]!r}")
        except (OSError, ValueError, KeyError, TypeError):
            continue
    if not rows:
        return f"the cache {root} holds no library of {model!r}"
    return (f"the cache {root} holds {model!r} built with " + "; ".join(rows) + ", which differ from this machine's "
            "settings (ABYSSAL_CFLAGS, ABYSSAL_CC/CC, and the CPU for -march=native flags) or sources")


def build(model: str, sources: dict[str, str], *, symbols=(), strict: bool = False, include_dirs=()) -> Path:
    """Path of the compiled library of `sources`, building it if no valid cache entry exists.

    `model` names the entry and the library (a C identifier, never a path); `symbols` are extra
    names the smoke test must find in the library; `strict` compiles every file with STRICT_FLAGS
    (hand-written C: warnings are errors); `include_dirs` are searched for headers the sources do
    not carry (a Python extension's Python.h; part of the key, as flags are).
    """
    if not (isinstance(model, str) and _IDENTIFIER.fullmatch(model)):
        raise ValueError(f"build(): model {model!r} must be a C identifier (the model's name, never a path)")
    for name in sources:
        if Path(name).name != name or name.startswith(".") or not name.endswith((".c", ".h")):
            raise ValueError(f"build(): source {name!r} must be a plain file name ending in .c or .h")
    flags = cflags() + [f"-I{folder}" for folder in include_dirs]
    requested_var, requested = _requested_compiler()
    key = cache_key(sources, flags, requested, strict)
    root = cache_dir()
    entry = root / f"{model}-{key[:24]}"
    lib_name = f"lib{model}.so"
    for _ in range(3):  # an entry evicted or replaced between validation and claim: look again
        lib = _valid_entry(entry, lib_name, key)
        if lib is None or _claim(entry):
            break
        lib = None
    if lib is not None:
        return lib
    try:
        cc = compiler()
    except CompilerNotFoundError as exc:
        raise CompilerNotFoundError(f"{exc}; no cached library either: {_near_misses(root, model)}") from None
    timeout = build_timeout()
    try:
        _ensure_root(root)
        lock = _KeyLock(root / f"{entry.name}.lock", wait=timeout + LOCK_MARGIN)
        with lock:
            lib = _valid_entry(entry, lib_name, key)  # another process may have built it while we waited
            if lib is None:
                _build_entry(model, sources, symbols, flags, (requested_var, requested), key, cc, timeout, entry, strict)
    except CacheError as exc:
        raise CacheError(f"{model}: {exc}") from exc.__cause__
    except OSError as exc:  # a read-only or full cache (EACCES, EROFS, ENOSPC, EDQUOT, ...): named, never raw
        why = {errno.EACCES: "is not writable", errno.EPERM: "is not writable", errno.EROFS: "is on a read-only file "
               "system", errno.ENOSPC: "has no space left", errno.EDQUOT: "is over its disk quota"}.get(exc.errno,
                                                                                                     "cannot be written")
        raise CacheError(f"{model}: cannot build its library into the cache: {_describe_root(root)} {why} ({exc}); free "
                         "space there or set ABYSSAL_CACHE_DIR to a writable folder") from exc
    lib = _valid_entry(entry, lib_name, key)
    if lib is None or not _claim(entry):
        raise BuildError(f"cache entry {entry} is not valid right after building it")
    evict(keep={entry})
    return lib


def _build_entry(model, sources, symbols, flags, requested, key, cc, timeout, entry, strict) -> None:
    """Compile into a temporary folder, smoke-test, describe, and rename it to `entry`."""
    (requested_var, requested), root, lib_name = requested, entry.parent, f"lib{model}.so"
    deadline = time.monotonic() + timeout
    work = Path(tempfile.mkdtemp(prefix=f".{model}-", dir=root))
    try:
        lib = work / lib_name
        try:
            with _Progress(model, sources):
                _compile(sources, work, lib, flags, cc, deadline, timeout, strict)
        except BuildError as exc:
            notes = [f"ABYSSAL_CFLAGS={os.environ['ABYSSAL_CFLAGS']!r}"] if "ABYSSAL_CFLAGS" in os.environ else []
            notes += [f"{requested_var}={requested!r}"] if requested_var else []
            raise BuildError(f"{model}: {exc}" + (f"\n(settings: {', '.join(notes)})" if notes else "")) from None
        smoke_test(lib, sources, symbols)
        meta = {
            "format": ENTRY_FORMAT, "model": model, "key": key, "sha256": _sha256_file(lib), "bytes": lib.stat().st_size,
            "flags": flags, "target": target_identity(flags), "sources": sorted(sources),
            "compiler": {"requested": requested, "path": cc, "version": _compiler_identity(cc)},
            "built": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
        for leftover in work.iterdir():
            if leftover.name != lib_name:
                leftover.unlink()
        (work / "entry.json").write_text(json.dumps(meta, indent=1))
        (work / MARKER).touch()
        os.chmod(work, 0o755)
        if os.path.lexists(entry):
            _remove(entry, root)  # not a valid entry: replaced, never trusted
        os.rename(work, entry)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


# ------------------------------------------------------------------------------------ size cap
@dataclass
class Entry:
    path: Path
    bytes: int
    last_used: float
    model: str


def _size(path: Path) -> int:
    if path.is_symlink() or not path.is_dir():
        return path.lstat().st_size
    return sum(p.lstat().st_size for p in path.rglob("*"))


def entries(root: Path | None = None) -> list[Entry]:
    """The entries of the cache (anything named like one), least recently used first."""
    root = cache_dir() if root is None else root
    found = []
    if not root.is_dir():
        return found
    for path in root.iterdir():
        if path.name.startswith(".") or path.name.endswith(".lock"):
            continue
        try:
            stamps = [(path / name).stat().st_mtime for name in (MARKER, "entry.json") if (path / name).exists()]
            stamp = max(stamps) if stamps and path.is_dir() else path.lstat().st_mtime
            found.append(Entry(path, _size(path), stamp, path.name.rsplit("-", 1)[0]))
        except OSError:
            continue  # removed while we looked
    return sorted(found, key=lambda e: e.last_used)


def _try_remove_entry(path: Path, root: Path) -> bool:
    """Remove an entry unless a process uses it (holds its marker's shared flock)."""
    if path in _IN_USE:
        return False
    marker = path / MARKER
    if path.is_dir() and not path.is_symlink() and marker.exists():
        try:
            fd = os.open(marker, os.O_RDONLY)
        except OSError:
            fd = None
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                return False
            try:
                _remove(path, root)
            finally:
                os.close(fd)
            return True
    _remove(path, root)
    return True


def _remove_leftovers(root: Path, older_than: float) -> None:
    """Temporary build folders of builds that cannot still be running, interrupted deletions, and
    lock files nobody holds (older versions of abyssal left them behind)."""
    for path in root.glob("*.lock"):
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if _same_file(fd, path):
                os.unlink(path)  # a waiter on this inode re-checks the path after locking (_KeyLock)
        except OSError:
            pass  # held: a build is running
        finally:
            os.close(fd)
    now = time.time()
    for path in root.glob(".*"):
        try:
            age = now - path.lstat().st_mtime
            if age > older_than or (path.name.startswith(".trash-") and age > 60):
                shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink()
        except OSError:
            pass


def evict(keep=(), root: Path | None = None, limit: int | None = None) -> list[Path]:
    """Remove least-recently-used entries until the cache is within `limit` (default max_bytes()).

    Never removes an entry in `keep` or in use by any process. Returns the removed entries.
    """
    root = cache_dir() if root is None else root
    limit = max_bytes() if limit is None else limit
    if not root.is_dir():
        return []
    _remove_leftovers(root, older_than=2 * build_timeout() + 60)
    found = entries(root)
    total = sum(e.bytes for e in found)
    removed = []
    for e in found:
        if total <= limit:
            break
        if e.path in keep or not _try_remove_entry(e.path, root):
            continue
        total -= e.bytes
        removed.append(e.path)
    return removed


def info() -> dict:
    """The cache's folder, entries (least recently used first), total size and cap."""
    root = cache_dir()
    found = entries(root)
    rows = []
    for e in found:
        meta = {}
        try:
            meta = json.loads((e.path / "entry.json").read_text())
        except (OSError, ValueError):
            pass
        valid = isinstance(meta, dict) and _valid_entry(e.path, f"lib{e.model}.so", meta.get("key")) is not None
        rows.append({"name": e.path.name, "model": e.model, "bytes": e.bytes,
                     "last_used": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(e.last_used)),
                     "compiler": (meta.get("compiler") or {}).get("version") if valid else None, "valid": valid})
    return {"folder": str(root), "entries": rows, "total_bytes": sum(e.bytes for e in found), "max_bytes": max_bytes(),
            "build_timeout_s": build_timeout()}


def clear() -> tuple[int, int]:
    """Remove every entry not in use by a process, and leftovers; (removed, kept in use)."""
    root = cache_dir()
    if not root.is_dir():
        return 0, 0
    removed = kept = 0
    for e in entries(root):
        if _try_remove_entry(e.path, root):
            removed += 1
        else:
            kept += 1
    _remove_leftovers(root, older_than=2 * build_timeout() + 60)
    return removed, kept
