"""Shared fixtures.

Most tests use the normal compile cache, so each model's generated C compiles at most once per
session (and usually not at all). Tests of the cache itself take `isolated_cache`, which points
ABYSSAL_CACHE_DIR at a fresh folder under one session-wide temporary root.
"""
from __future__ import annotations

import itertools

import pytest

import abyssal.generated


@pytest.fixture(scope="session")
def isolated_cache_root(tmp_path_factory):
    """A session-wide temporary folder holding the isolated caches of the tests that need one."""
    return tmp_path_factory.mktemp("abyssal-cache")


_counter = itertools.count()


@pytest.fixture
def isolated_cache(isolated_cache_root, monkeypatch):
    """A fresh, empty ABYSSAL_CACHE_DIR for this test only (restored afterwards)."""
    folder = isolated_cache_root / f"cache{next(_counter)}"
    monkeypatch.setenv("ABYSSAL_CACHE_DIR", str(folder))
    return folder


@pytest.fixture(scope="session")
def rov():
    return abyssal.generated.load("rov4dof")


@pytest.fixture(scope="session")
def cn():
    return abyssal.generated.load("cn2d")
