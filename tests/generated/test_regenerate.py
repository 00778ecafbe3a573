"""`abyssal regenerate --check`: the committed C matches the equations, and drift is detected.

Drift tests work on a temporary copy of generated/ (regenerate.GENERATED_DIR is monkeypatched);
the real committed files are never written.
"""
from __future__ import annotations

import shutil

import pytest

from abyssal.generated import regenerate


def test_committed_tree_matches_the_equations():
    assert regenerate.check() == []


@pytest.fixture
def generated_copy(tmp_path, monkeypatch):
    copy = tmp_path / "generated"
    shutil.copytree(regenerate.GENERATED_DIR / "cn2d", copy / "cn2d")
    monkeypatch.setattr(regenerate, "GENERATED_DIR", copy)
    assert regenerate.check(["cn2d"]) == []  # the copy starts clean
    return copy / "cn2d"


def test_edited_file_is_reported_with_a_diff(generated_copy):
    path = generated_copy / "cn2d_model.c"
    path.write_text(path.read_text().replace("casadi_real a0", "casadi_real a0 /* hand edit */", 1))
    problems = regenerate.check(["cn2d"])
    assert len(problems) == 1
    assert problems[0].startswith("differs: generated/cn2d/cn2d_model.c")
    assert "hand edit" in problems[0]


def test_missing_and_stale_files_are_reported(generated_copy):
    (generated_copy / "cn2d_soa.c").unlink()
    (generated_copy / "cn2d_old.c").write_text("/* no longer generated */\n")
    problems = regenerate.check(["cn2d"])
    assert "missing: generated/cn2d/cn2d_soa.c" in problems
    assert any(p.startswith("stale: generated/cn2d/cn2d_old.c") for p in problems)


def test_edited_manifest_is_drift(generated_copy):
    path = generated_copy / "manifest.json"
    path.write_text(path.read_text().replace('"euler"', '"rk4"'))
    assert [p.splitlines()[0] for p in regenerate.check(["cn2d"])] == ["differs: generated/cn2d/manifest.json"]


def test_regenerate_restores_the_copy(generated_copy):
    (generated_copy / "cn2d_model.c").write_text("garbage\n")
    (generated_copy / "cn2d_old.c").write_text("stale\n")
    written = regenerate.regenerate(["cn2d"])
    assert generated_copy / "cn2d_model.c" in written and generated_copy / "cn2d_old.c" in written
    assert not (generated_copy / "cn2d_old.c").exists()
    assert regenerate.check(["cn2d"]) == []


def test_unknown_model_is_a_key_error():
    with pytest.raises(KeyError, match="unknown model"):
        regenerate.check(["no_such_model"])
