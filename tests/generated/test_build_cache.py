"""The compile cache (generated/build.py): one build per key, damaged entries rebuilt, concurrent
builders serialised, compiler faults bounded and never cached, a valid entry used without a
compiler, the size cap, and clear errors naming the environment variable at fault.

Every test uses an isolated cache folder. Most compile TINY, a few lines of C (~0.1 s); the
ones that need a real generated file use cn2d's small model file (~1 s). Misbehaving compilers
are small shell scripts in tmp_path, with timeouts of about a second.
"""
from __future__ import annotations

import ctypes
import importlib
import json
import multiprocessing
import os
import re
import shutil
import stat
import time
from pathlib import Path

import pytest

from abyssal import generated
from abyssal.generated.build import (BuildError, CacheError, CompilerNotFoundError, build, cache_key, cflags, compiler)
from abyssal.runtime import cli

# the module itself (abyssal.generated re-exports the function `build` under the same name)
build_mod = importlib.import_module("abyssal.generated.build")

TINY_TEMPLATE = """
#define CASADI_SYMBOL_EXPORT __attribute__ ((visibility ("default")))
typedef long long int casadi_int;
CASADI_SYMBOL_EXPORT casadi_int tiny_f_n_in(void) { return 2;}
CASADI_SYMBOL_EXPORT casadi_int tiny_f_n_out(void) { return 1;}
CASADI_SYMBOL_EXPORT double tiny_f(double x) { return x + %d.0; }
"""


def tiny(k: int = 1) -> dict[str, str]:
    return {"tiny.c": TINY_TEMPLATE % k}


@pytest.fixture(scope="module")
def small_sources():
    _, sources = generated.read_sources("cn2d")
    return {"cn2d_model.c": sources["cn2d_model.c"]}


@pytest.fixture
def count_compiles(monkeypatch):
    calls = []
    original = build_mod._compile

    def counting(*args, **kwargs):
        calls.append(args[0])
        return original(*args, **kwargs)

    monkeypatch.setattr(build_mod, "_compile", counting)
    return calls


def fake_compiler(tmp_path: Path, body: str, name: str = "fakecc") -> Path:
    """An executable shell script; `$OUT` is the argument after -o, `$REAL` the real compiler."""
    path = tmp_path / name
    path.write_text(
        "#!/bin/sh\n"
        f'REAL="{compiler()}"\nLOG="{tmp_path}/pids"\n'
        'OUT=""; prev=""\nfor a in "$@"; do [ "$prev" = "-o" ] && OUT="$a"; prev="$a"; done\n'
        + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def assert_all_dead(pid_file: Path):
    pids = [int(p) for p in pid_file.read_text().split()]
    assert pids, "the fake compiler never ran"
    for _ in range(100):  # the kernel reaps killed orphans asynchronously
        if not any(alive(p) for p in pids):
            return
        time.sleep(0.05)
    raise AssertionError(f"compiler processes left running: {[p for p in pids if alive(p)]}")


def assert_no_leftovers(cache: Path):
    """No temporary build folder, no lock file, no published entry."""
    left = sorted(p.name for p in cache.iterdir()) if cache.exists() else []
    assert left == [], left


def replace_file(path: Path, data: bytes):
    """Damage an entry the way a disk or a user might, without writing into a file this process has
    mapped (that is exactly what the module docstring forbids: it ends the process with SIGBUS)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


# ---------------------------------------------------------------------------------- basics
def test_builds_once_per_key(isolated_cache, small_sources, count_compiles):
    first = build("cn2d", small_sources)
    second = build("cn2d", small_sources)
    assert first == second and first.is_file()
    assert len(count_compiles) == 1
    assert first.parent.parent == isolated_cache
    ctypes.CDLL(str(first)).cn2d_f  # exported symbol is there
    meta = json.loads((first.parent / "entry.json").read_text())
    assert meta["format"] == build_mod.ENTRY_FORMAT and meta["sha256"] == build_mod._sha256_file(first)
    assert meta["compiler"]["path"] == compiler() and meta["compiler"]["version"]
    assert sorted(p.name for p in first.parent.iterdir()) == ["entry.json", "last_used", "libcn2d.so"]
    assert sorted(p.name for p in isolated_cache.iterdir()) == [first.parent.name]  # lock file removed


def test_key_changes_with_sources_flags_and_requested_compiler(monkeypatch):
    sources = tiny()
    base = cache_key(sources, cflags(), "default")
    assert cache_key({"tiny.c": sources["tiny.c"] + "/* changed */"}, cflags(), "default") != base
    assert cache_key(sources, [*cflags(), "-DX=1"], "default") != base
    assert cache_key(sources, cflags(), "clang") != base
    assert cache_key(sources, cflags(), "default") == base
    # the CPU is part of the key only for native flags; the architecture always is
    monkeypatch.setattr(build_mod, "_cpu_identity", lambda: "another cpu")
    assert cache_key(sources, cflags(), "default") != base
    portable = ["-O2", "-fPIC"]
    assert build_mod.target_identity(portable) == build_mod.platform.machine()


def test_key_needs_no_compiler(monkeypatch, tmp_path):
    """The lookup never runs (or even finds) a compiler: `--version` is only run when building."""
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("ABYSSAL_CC", raising=False)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(build_mod, "_compiler_identity", lambda cc: pytest.fail("compiler run for a key"))
    assert len(cache_key(tiny(), cflags())) == 64


def test_different_sources_get_a_new_entry(isolated_cache, count_compiles):
    a = build("tiny", tiny(1))
    b = build("tiny", tiny(2))
    assert a != b and len(count_compiles) == 2


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete_library", "bad_meta", "no_meta", "foreign_meta",
                                    "file_instead_of_folder", "empty_folder", "library_is_a_folder"])
def test_damaged_entry_is_rebuilt_not_trusted(isolated_cache, count_compiles, damage):
    lib = build("tiny", tiny())
    entry, good = lib.parent, lib.read_bytes()
    assert len(count_compiles) == 1
    if damage == "truncate":
        replace_file(lib, good[: len(good) // 2])
    elif damage == "flip":
        replace_file(lib, good[:100] + bytes([good[100] ^ 0xFF]) + good[101:])
    elif damage == "delete_library":
        lib.unlink()
    elif damage == "bad_meta":
        replace_file(entry / "entry.json", b"{not json")
    elif damage == "no_meta":
        (entry / "entry.json").unlink()
    elif damage == "foreign_meta":  # a valid-looking entry.json of another key
        meta = json.loads((entry / "entry.json").read_text())
        replace_file(entry / "entry.json", json.dumps({**meta, "key": "0" * 64}).encode())
    elif damage == "file_instead_of_folder":
        shutil.rmtree(entry)
        entry.write_text("not an entry")
    elif damage == "empty_folder":
        shutil.rmtree(entry)
        entry.mkdir()
    else:
        lib.unlink()
        lib.mkdir()
    rebuilt = build("tiny", tiny())
    assert len(count_compiles) == 2
    assert rebuilt == lib and rebuilt.is_file()
    meta = json.loads((rebuilt.parent / "entry.json").read_text())
    assert meta["sha256"] == build_mod._sha256_file(rebuilt)
    ctypes.CDLL(str(rebuilt)).tiny_f
    assert not [p for p in isolated_cache.iterdir() if p.name.startswith(".") or p.suffix == ".lock"]


def test_rebuild_never_writes_into_a_published_library(isolated_cache, count_compiles):
    """A process that has the old library open keeps seeing the same bytes: rebuilds replace, never rewrite."""
    lib = build("tiny", tiny())
    with open(lib, "rb") as held:
        before = held.read()
        replace_file(lib.parent / "entry.json", b"{}")
        rebuilt = build("tiny", tiny())
        assert len(count_compiles) == 2
        held.seek(0)
        assert held.read() == before
        assert os.fstat(held.fileno()).st_ino != rebuilt.stat().st_ino


def _build_in_child(sources, barrier, marks_dir, results):
    """Child process: count own compiles by marker files, wait for the sibling, build."""
    original = build_mod._compile

    def marking(*args, **kwargs):
        (marks_dir / f"compile-{os.getpid()}").write_text("")
        return original(*args, **kwargs)

    build_mod._compile = marking
    barrier.wait()
    results.put(str(build("cn2d", sources)))


def test_two_processes_building_the_same_key_build_once(isolated_cache, small_sources, tmp_path):
    ctx = multiprocessing.get_context("fork")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    marks = tmp_path / "marks"
    marks.mkdir()
    procs = [ctx.Process(target=_build_in_child, args=(small_sources, barrier, marks, results)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    assert [p.exitcode for p in procs] == [0, 0]
    paths = {results.get(timeout=5), results.get(timeout=5)}
    assert len(paths) == 1 and os.path.isfile(paths.pop())
    assert len(list(marks.iterdir())) == 1  # one compile: the second process found the published entry
    assert not [p for p in isolated_cache.iterdir() if p.name.startswith(".")]  # no half-built folder left


def test_a_path_is_never_a_model_name(isolated_cache):
    for bad in ("/some/dir", "../escape", "a/b", "", "1abc"):
        with pytest.raises(ValueError, match="C identifier"):
            build(bad, tiny())
    with pytest.raises(ValueError, match="plain file name"):
        build("tiny", {"../tiny.c": TINY_TEMPLATE % 1})
    assert not isolated_cache.exists()


# ---------------------------------------------------------------------------------- compiler faults
def test_missing_compiler_named_by_abyssal_cc(monkeypatch):
    monkeypatch.setenv("ABYSSAL_CC", "/nowhere/abyssal-test-cc")
    with pytest.raises(CompilerNotFoundError, match="ABYSSAL_CC='/nowhere/abyssal-test-cc'"):
        compiler()
    monkeypatch.delenv("ABYSSAL_CC")
    monkeypatch.setenv("CC", "no-such-compiler-xyz")
    with pytest.raises(CompilerNotFoundError, match="CC='no-such-compiler-xyz'"):
        compiler()


def test_no_compiler_on_path(monkeypatch, tmp_path, isolated_cache):
    monkeypatch.delenv("ABYSSAL_CC", raising=False)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(CompilerNotFoundError, match="cc, gcc, clang.*no cached library"):
        build("tiny", tiny())


def test_valid_cached_library_needs_no_compiler(monkeypatch, tmp_path, isolated_cache, count_compiles):
    """A deployed vehicle computer: the cache was filled elsewhere, no compiler here."""
    monkeypatch.delenv("ABYSSAL_CC", raising=False)
    monkeypatch.delenv("CC", raising=False)
    lib = build("tiny", tiny())
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc or clang any more
    monkeypatch.setattr(build_mod, "_compiler_identity", lambda cc: pytest.fail("compiler run for a cached library"))
    assert build("tiny", tiny()) == lib and len(count_compiles) == 1
    # a miss explains what the cache holds instead
    monkeypatch.setenv("ABYSSAL_CFLAGS", "-O1 -fPIC")
    with pytest.raises(CompilerNotFoundError, match="holds 'tiny' built with flags '-O3"):
        build("tiny", tiny())


def test_a_read_only_copy_of_the_cache_is_used(monkeypatch, tmp_path, isolated_cache):
    """Ship the cache folder read-only (e.g. on a vehicle's read-only root file system)."""
    lib = build("tiny", tiny(7))
    shipped = tmp_path / "shipped"
    shutil.copytree(isolated_cache, shipped)
    for path in [shipped, *shipped.rglob("*")]:
        path.chmod(path.stat().st_mode & ~0o222)
    try:
        monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(shipped))
        monkeypatch.setenv("PATH", str(tmp_path))
        monkeypatch.delenv("ABYSSAL_CC", raising=False)
        monkeypatch.delenv("CC", raising=False)
        used = build("tiny", tiny(7))
        assert used == shipped / lib.parent.name / lib.name
        fn = ctypes.CDLL(str(used)).tiny_f
        fn.restype, fn.argtypes = ctypes.c_double, [ctypes.c_double]
        assert fn(1.0) == 8.0
    finally:
        for path in [shipped, *shipped.rglob("*")]:
            path.chmod(path.stat().st_mode | 0o200)


def test_hanging_compiler_times_out_releases_the_lock_and_cleans_up(monkeypatch, tmp_path, isolated_cache):
    cc = fake_compiler(tmp_path, 'echo $$ >> "$LOG"\n[ "$1" = "--version" ] && { echo fakecc; exit 0; }\n'
                                 'sleep 60 & echo $! >> "$LOG"\nwait')
    monkeypatch.setenv("ABYSSAL_CC", str(cc))
    monkeypatch.setenv("ABYSSAL_BUILD_TIMEOUT", "1")
    with pytest.raises(BuildError, match=r"did not finish within 1 s \(ABYSSAL_BUILD_TIMEOUT\) and was stopped while "
                                         r"compiling tiny\.c"):
        build("tiny", tiny())
    assert_all_dead(tmp_path / "pids")  # the compiler and its child
    assert_no_leftovers(isolated_cache)  # no temporary folder, no lock file, nothing published
    monkeypatch.delenv("ABYSSAL_CC")
    assert build("tiny", tiny()).is_file()  # the lock is free


def test_a_build_lock_held_too_long_is_an_error_not_a_hang(monkeypatch, isolated_cache):
    """Another process stuck holding the key's lock: give up after the timeout, naming the lock."""
    import fcntl

    monkeypatch.setenv("ABYSSAL_BUILD_TIMEOUT", "1")
    monkeypatch.setattr(build_mod, "LOCK_MARGIN", 0.0)
    isolated_cache.mkdir()
    key = cache_key(tiny(), cflags())
    lock_path = isolated_cache / f"tiny-{key[:24]}.lock"
    with open(lock_path, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # a separate open file: conflicts like another process would
        with pytest.raises(BuildError, match="another process has held .*tiny-.*lock"):
            build("tiny", tiny())


@pytest.mark.parametrize("garbage", ["not_a_library", "no_symbols", "wrong_counts"])
def test_a_broken_library_is_never_cached(monkeypatch, tmp_path, isolated_cache, garbage):
    bodies = {
        # writes junk wherever it is asked to write
        "not_a_library": "printf 'this is not an ELF file' > \"$OUT\"",
        # compiles an empty file instead of the source: a valid library without the symbols
        "no_symbols": 'case " $* " in *" -c "*) echo "" > "$OUT.c"; exec "$REAL" -fPIC -c "$OUT.c" -o "$OUT";; '
                      '*) exec "$REAL" "$@";; esac',
        # miscompiles: every n_in returns 3
        "wrong_counts": 'case " $* " in *" -c "*) for a in "$@"; do case "$a" in *.c) SRC="$a";; esac; done; '
                        'sed "s/return 2;/return 3;/" "$SRC" > "$OUT.c"; exec "$REAL" -fPIC -c "$OUT.c" -o "$OUT";; '
                        '*) exec "$REAL" "$@";; esac',
    }
    cc = fake_compiler(tmp_path, '[ "$1" = "--version" ] && { echo fakecc; exit 0; }\n' + bodies[garbage])
    monkeypatch.setenv("ABYSSAL_CC", str(cc))
    message = {"not_a_library": "cannot be loaded", "no_symbols": "lacks the symbol 'tiny_f",
               "wrong_counts": r"tiny_f_n_in\(\) returned 3, its source says 2"}[garbage]
    with pytest.raises(BuildError, match=message):
        build("tiny", tiny())
    assert_no_leftovers(isolated_cache)


def test_hanging_version_costs_seconds_not_the_build(monkeypatch, tmp_path, isolated_cache):
    cc = fake_compiler(tmp_path, '[ "$1" = "--version" ] && { sleep 60 & echo $! >> "$LOG"; wait; }\nexec "$REAL" "$@"')
    monkeypatch.setenv("ABYSSAL_CC", str(cc))
    monkeypatch.setattr(build_mod, "VERSION_TIMEOUT", 0.5)
    lib = build("tiny", tiny())
    meta = json.loads((lib.parent / "entry.json").read_text())
    assert meta["compiler"]["version"].startswith("unknown (") and "did not answer within 0.5 s" in meta["compiler"]["version"]
    assert meta["compiler"]["requested"] == str(cc)
    assert_all_dead(tmp_path / "pids")


def test_compiler_error_is_a_build_error(isolated_cache):
    with pytest.raises(BuildError, match="broken.c"):
        build("broken", {"broken.c": "this is not C;\n"})
    assert_no_leftovers(isolated_cache)


# ---------------------------------------------------------------------------------- environment
def test_environment_errors_name_the_variable(monkeypatch, tmp_path, isolated_cache):
    monkeypatch.setenv("ABYSSAL_CFLAGS", '-O2 "-DUNCLOSED')
    with pytest.raises(ValueError, match="ABYSSAL_CFLAGS="):
        build("tiny", tiny())
    monkeypatch.setenv("ABYSSAL_CFLAGS", "-O2 -fPIC -fno-such-flag-abyssal")
    with pytest.raises(BuildError, match="ABYSSAL_CFLAGS='-O2 -fPIC -fno-such-flag-abyssal'"):
        build("tiny", tiny())
    monkeypatch.delenv("ABYSSAL_CFLAGS")
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(a_file))
    with pytest.raises(CacheError, match="ABYSSAL_CACHE_DIR=.*a_file.* is not a folder"):
        build("tiny", tiny())
    monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(a_file / "below"))
    with pytest.raises(CacheError, match="ABYSSAL_CACHE_DIR=.*cannot be created"):
        build("tiny", tiny())
    monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(isolated_cache))
    for var, value in (("ABYSSAL_BUILD_TIMEOUT", "soon"), ("ABYSSAL_BUILD_TIMEOUT", "-1"),
                       ("ABYSSAL_CACHE_MAX_BYTES", "lots")):
        monkeypatch.setenv(var, value)
        with pytest.raises(ValueError, match=f"{var}='{value}'"):
            build_mod.build_timeout() if var == "ABYSSAL_BUILD_TIMEOUT" else build_mod.max_bytes()
        monkeypatch.delenv(var)


def test_max_bytes_accepts_sizes(monkeypatch):
    assert build_mod.max_bytes() == 1 << 30
    for text, value in (("12345", 12345), ("500M", 500 << 20), ("2G", 2 << 30), ("1.5GiB", 3 << 29), ("64k", 64 << 10)):
        monkeypatch.setenv("ABYSSAL_CACHE_MAX_BYTES", text)
        assert build_mod.max_bytes() == value


# ---------------------------------------------------------------------------------- size cap
def _build_and_exit(sources, k):
    build("tiny", sources)


def build_elsewhere(sources):
    """Build in a short-lived process: its entry is then in use by nobody."""
    proc = multiprocessing.get_context("fork").Process(target=_build_and_exit, args=(sources, 0))
    proc.start()
    proc.join(timeout=60)
    assert proc.exitcode == 0


def entry_of(sources) -> Path:
    return build_mod.cache_dir() / f"tiny-{cache_key(sources, cflags())[:24]}"


def age(entry: Path, seconds_ago: float):
    stamp = time.time() - seconds_ago
    os.utime(entry / "last_used", (stamp, stamp))


def test_least_recently_used_entries_are_evicted_over_the_cap(monkeypatch, isolated_cache):
    a, b, c = tiny(1), tiny(2), tiny(3)
    for i, sources in enumerate((a, b)):
        build_elsewhere(sources)
        age(entry_of(sources), 1000 - i)  # a is the oldest
    size = build_mod._size(entry_of(a))
    monkeypatch.setenv("ABYSSAL_CACHE_MAX_BYTES", str(int(2.5 * size)))
    build("tiny", c)
    assert not entry_of(a).exists() and entry_of(b).is_dir() and entry_of(c).is_dir()
    # a load records its access time: b becomes the most recent, so the next eviction takes c... unless in use
    build_elsewhere(b)
    assert (entry_of(b) / "last_used").stat().st_mtime > time.time() - 60
    build("tiny", a)
    assert entry_of(c).is_dir(), "an entry in use by this process was evicted"
    assert not entry_of(b).exists()


def _hold(sources, ready, done):
    build("tiny", sources)
    ready.set()
    done.wait(60)


def test_an_entry_in_use_by_another_process_is_never_evicted(monkeypatch, isolated_cache):
    ctx = multiprocessing.get_context("fork")
    ready, done = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold, args=(tiny(1), ready, done))
    holder.start()
    try:
        assert ready.wait(60)
        age(entry_of(tiny(1)), 1000)
        monkeypatch.setenv("ABYSSAL_CACHE_MAX_BYTES", "1")
        build("tiny", tiny(2))
        assert entry_of(tiny(1)).is_dir() and entry_of(tiny(2)).is_dir()
    finally:
        done.set()
        holder.join(30)
    build_elsewhere(tiny(3))  # the holder is gone: now its entry goes
    assert not entry_of(tiny(1)).exists() and entry_of(tiny(2)).is_dir()


# ---------------------------------------------------------------------------------- abyssal cache
def test_cache_info_and_clear(capsys, monkeypatch, isolated_cache):
    build_elsewhere(tiny(1))
    lib = build("tiny", tiny(2))  # in use by this process: clear keeps it
    (isolated_cache / ".tiny-stale").mkdir()
    old = time.time() - 10 * build_mod.DEFAULT_TIMEOUT
    os.utime(isolated_cache / ".tiny-stale", (old, old))
    assert cli.main(["cache", "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["folder"] == str(isolated_cache) and info["max_bytes"] == 1 << 30
    assert len(info["entries"]) == 2 and all(e["valid"] for e in info["entries"])
    assert info["total_bytes"] == sum(e["bytes"] for e in info["entries"]) > 0
    assert cli.main(["cache", "info"]) == 0
    text = capsys.readouterr().out
    assert str(isolated_cache) in text and "2 entries" in text and "1.0 GiB" in text
    assert cli.main(["cache", "clear"]) == 0
    assert "removed 1 entry" in capsys.readouterr().out
    assert sorted(p.name for p in isolated_cache.iterdir()) == [lib.parent.name]


def test_stale_lock_files_are_removed_held_ones_kept(isolated_cache):
    """Older versions left `<entry>.lock` files behind; `clear` (and eviction) remove those nobody holds."""
    import fcntl

    isolated_cache.mkdir()
    (isolated_cache / "cn2d-0123456789abcdef01234567.lock").write_text("")
    held_path = isolated_cache / "tiny-0123456789abcdef01234567.lock"
    with open(held_path, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # a build in progress
        build_mod.clear()
        assert sorted(p.name for p in isolated_cache.iterdir()) == [held_path.name]
    build_mod.clear()
    assert list(isolated_cache.iterdir()) == []


def test_a_header_is_written_but_not_compiled(isolated_cache):
    lib = build("tiny", {"tiny.h": "#define K 5.0\n", "tiny.c": '#include "tiny.h"\ndouble tiny_f(double x) { return x + K; }\n'})
    fn = ctypes.CDLL(str(lib)).tiny_f
    fn.restype, fn.argtypes = ctypes.c_double, [ctypes.c_double]
    assert fn(1.0) == 6.0


def test_the_smoke_test_checks_symbols_the_caller_names(isolated_cache):
    with pytest.raises(BuildError, match="lacks the symbol 'tiny_g'"):
        build("tiny", tiny(), symbols=("tiny_f", "tiny_g"))
    assert build("tiny", tiny(), symbols=("tiny_f",)).is_file()


def test_a_slow_build_prints_one_progress_line_and_a_quick_one_none(monkeypatch, tmp_path, isolated_cache, capfd):
    slow = fake_compiler(tmp_path, '[ "$1" = "--version" ] && { echo fakecc; exit 0; }\nsleep 0.6\nexec "$REAL" "$@"')
    monkeypatch.setattr(build_mod, "PROGRESS_AFTER", 0.3)
    monkeypatch.setenv("ABYSSAL_CC", str(slow))
    build("tiny", tiny(3))
    err = capfd.readouterr().err
    assert re.fullmatch(r"abyssal: compiling tiny: 1 files, 0\.00 MB of C \.\.\. done in \d+\.\d s\n", err), err
    monkeypatch.setattr(build_mod, "PROGRESS_AFTER", 30.0)
    build("tiny", tiny(4))
    assert capfd.readouterr().err == ""
