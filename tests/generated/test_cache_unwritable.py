"""A cache that cannot take a new library (a full disk, a read-only file system, no permission): the error names the
cache folder and the model, says what to do, and is one line from the command (issue 33: it was a raw OSError naming
neither)."""
from __future__ import annotations

import errno
import importlib
import os

import pytest

build = importlib.import_module("abyssal.generated.build")
SOURCES = {"toy_model.c": "double toy_model_twice(double x) { return 2.0 * x; }\n"}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("code, words", [(errno.ENOSPC, "has no space left"), (errno.EROFS, "read-only file system"),
                                         (errno.EACCES, "is not writable")])
def test_an_unwritable_cache_names_the_cache_and_the_model(isolated_cache, monkeypatch, code, words):
    def refuse(*args, **kwargs):
        raise OSError(code, os.strerror(code), str(isolated_cache))

    monkeypatch.setattr(build.tempfile, "mkdtemp", refuse)  # where a build first writes into the cache
    with pytest.raises(build.CacheError) as info:
        build.build("toy_model", SOURCES)
    message = str(info.value)
    assert message.startswith("toy_model: ") and f"ABYSSAL_CACHE_DIR={str(isolated_cache)!r}" in message
    assert words in message and "set ABYSSAL_CACHE_DIR to a writable folder" in message and "\n" not in message


@pytest.mark.timeout(120)
def test_a_cache_folder_that_cannot_be_created_names_the_model_too(isolated_cache, monkeypatch):
    isolated_cache.parent.mkdir(parents=True, exist_ok=True)
    monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(isolated_cache / "sub"))

    def refuse(self, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(build.Path, "mkdir", refuse)
    with pytest.raises(build.CacheError, match=r"^toy_model: ABYSSAL_CACHE_DIR=.* cannot be created"):
        build.build("toy_model", SOURCES)
