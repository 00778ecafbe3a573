"""A non-editable install (pip install . into a fresh venv) generates into a user folder and never
writes into site-packages; `abyssal regenerate` of the built-ins refuses there and writes nothing.

Fast and offline: the fresh venv reuses this venv's site-packages for the dependencies (a .pth
line), pip runs with --no-deps --no-build-isolation --no-index (~3 s), and the compiled example
comes from the shared cache. Marked `install` (deselect with -m "not install").
"""
from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "own_vehicle" / "cybership.py"
pytestmark = pytest.mark.install


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


def test_non_editable_install_writes_only_into_the_user_folder(tmp_path):
    pytest.importorskip("wheel")  # setuptools < 70 builds wheels with it
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".venv", ".git", "__pycache__", "*.egg-info", "build",
                                                                  "tests", "benchmarks", "out", ".pytest_cache"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = Path(subprocess.run([venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                  capture_output=True, text=True, check=True).stdout.strip())
    (purelib / "_abyssal_test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([venv / "bin" / "python", "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--no-index", str(source)], check=True, capture_output=True)
    installed = purelib / "abyssal"
    assert (installed / "generated" / "rov4dof" / "manifest.json").is_file()
    before = _snapshot(purelib)

    project = tmp_path / "project"
    project.mkdir()
    shutil.copy(EXAMPLE, project / "cybership.py")
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    abyssal = str(venv / "bin" / "abyssal")

    refused = subprocess.run([abyssal, "regenerate"], cwd=project, env=env, capture_output=True, text=True)
    assert refused.returncode == 2
    assert "not a source checkout" in refused.stderr and "nothing was written" in refused.stderr

    made = subprocess.run([abyssal, "regenerate", "--model", "cybership.py:cybership", "--out", "gen"], cwd=project,
                          env=env, capture_output=True, text=True)
    assert made.returncode == 0, made.stderr
    assert (project / "gen" / "cybership" / "manifest.json").is_file()
    loaded = subprocess.run([venv / "bin" / "python", "-c",
                             "import abyssal; b = abyssal.load('gen/cybership'); print(abyssal.__file__, b.n_x)"],
                            cwd=project, env=env, capture_output=True, text=True)
    assert loaded.returncode == 0, loaded.stderr
    assert loaded.stdout.split() == [str(installed / "__init__.py"), "6"]
    checked = subprocess.run([abyssal, "regenerate", "--model", "cybership.py:cybership", "--out", "gen", "--check"],
                             cwd=project, env=env, capture_output=True, text=True)
    assert checked.returncode == 0, checked.stderr
    exported = subprocess.run([abyssal, "export", "gen/cybership", "--filter", "ekf", "--out", "cybership_ekf", "--steps",
                               "200"], cwd=project, env=env, capture_output=True, text=True)
    assert exported.returncode == 0, exported.stderr  # the runtime's C and the project's templates are package data
    for name in ("CMakeLists.txt", "include/abyssal_kalman.hpp", "src/abyssal_kalman.c", "examples/run_csv.c",
                 "tests/wrapper_test.cpp", "tests/vectors/expected.csv"):
        assert (project / "cybership_ekf" / name).is_file(), name
    inside = subprocess.run([abyssal, "regenerate", "--model", "cybership.py:cybership", "--out", str(installed)],
                            cwd=project, env=env, capture_output=True, text=True)
    assert inside.returncode == 2 and "never written to" in inside.stderr

    assert _snapshot(purelib) == before  # site-packages untouched


def test_every_folder_of_package_data_is_a_declared_package():
    """setuptools installs the files of a folder that is not a declared package only with a warning that it will stop
    (a wheel without the generated C or the runtime's): every folder under the package roots that holds tracked files
    other than Python is listed in pyproject.toml's packages, with package data of its own."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    roots = {folder: name for name, folder in config["package-dir"].items()}
    tracked = subprocess.run(["git", "ls-files", *roots], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    if not tracked.strip():
        pytest.skip("not a git checkout")
    folders = {Path(f).parent for f in tracked.split() if not f.endswith(".py")}
    for folder in sorted(folders):
        root = next(r for r in roots if folder.parts[0] == r)
        package = ".".join([roots[root], *folder.parts[1:]])
        assert package in config["packages"], f"{folder}/ holds package data: list {package!r} in pyproject's packages"
        assert package in config["package-data"], f"{package!r} has no package-data patterns in pyproject.toml"
