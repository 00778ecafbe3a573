"""The compile cache (generated/build.py): one build per key, damaged entries rebuilt, concurrent
builders serialised, clear errors without a compiler or with bad C. Every test here uses an
isolated cache folder and only cn2d's small model file, so builds take about a second."""
from __future__ import annotations

import ctypes
import importlib
import json
import multiprocessing
import os

import pytest

from abyssal import generated
from abyssal.generated.build import BuildError, CompilerNotFoundError, build, cache_key, cflags, compiler

# the module itself (abyssal.generated re-exports the function `build` under the same name)
build_mod = importlib.import_module("abyssal.generated.build")


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


def test_builds_once_per_key(isolated_cache, small_sources, count_compiles):
    first = build("cn2d", small_sources)
    second = build("cn2d", small_sources)
    assert first == second and first.is_file()
    assert len(count_compiles) == 1
    assert first.parent.parent == isolated_cache
    ctypes.CDLL(str(first)).cn2d_f  # exported symbol is there


def test_key_changes_with_sources_and_flags(small_sources):
    cc = compiler()
    base = cache_key(small_sources, cflags(), cc)
    edited = {k: v + "\n/* changed */\n" for k, v in small_sources.items()}
    assert cache_key(edited, cflags(), cc) != base
    assert cache_key(small_sources, [*cflags(), "-DX=1"], cc) != base
    assert cache_key(small_sources, cflags(), cc) == base


def test_different_sources_get_a_new_entry(isolated_cache, small_sources, count_compiles):
    a = build("cn2d", small_sources)
    b = build("cn2d", {k: v + "\n/* other */\n" for k, v in small_sources.items()})
    assert a != b and len(count_compiles) == 2


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete", "bad_meta"])
def test_damaged_entry_is_rebuilt_not_trusted(isolated_cache, small_sources, count_compiles, damage):
    lib = build("cn2d", small_sources)
    good = lib.read_bytes()
    assert len(count_compiles) == 1
    if damage == "truncate":
        lib.write_bytes(good[: len(good) // 2])
    elif damage == "flip":
        lib.write_bytes(good[:100] + bytes([good[100] ^ 0xFF]) + good[101:])
    elif damage == "delete":
        lib.unlink()
    else:
        (lib.parent / "entry.json").write_text("{not json")
    rebuilt = build("cn2d", small_sources)
    assert len(count_compiles) == 2
    assert rebuilt == lib and rebuilt.is_file()
    meta = json.loads((rebuilt.parent / "entry.json").read_text())
    assert meta["sha256"] == build_mod._sha256_file(rebuilt)
    ctypes.CDLL(str(rebuilt)).cn2d_f


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


def test_missing_compiler_named_by_abyssal_cc(monkeypatch):
    monkeypatch.setenv("ABYSSAL_CC", "/nowhere/abyssal-test-cc")
    with pytest.raises(CompilerNotFoundError, match="abyssal-test-cc"):
        compiler()


def test_no_compiler_on_path(monkeypatch, tmp_path, small_sources, isolated_cache):
    monkeypatch.delenv("ABYSSAL_CC", raising=False)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(CompilerNotFoundError, match="cc, gcc, clang"):
        build("cn2d", small_sources)


def test_compiler_error_is_a_build_error(isolated_cache):
    with pytest.raises(BuildError, match="broken.c"):
        build("broken", {"broken.c": "this is not C;\n"})
    assert not [p for p in isolated_cache.iterdir() if p.is_dir()]  # nothing published
