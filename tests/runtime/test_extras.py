"""The core install runs filters without the experiments extra; what needs the extra says so in one line.

A child process hides Dask, tqdm, scikit-learn, matplotlib (and verify's filterpy / scikit-fuzzy) behind an
import hook, as if they were not installed, then imports abyssal, runs a CKF and calls the CLI.
"""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from abyssal.runtime.extras import MissingExtraError, missing_optional, require

HIDDEN = ("dask", "distributed", "tqdm", "sklearn", "matplotlib", "filterpy", "skfuzzy")

CHILD = textwrap.dedent("""
    import importlib.abc, importlib.machinery, json, sys

    HIDDEN = {hidden!r}

    class Absent(importlib.abc.Loader):
        def create_module(self, spec):
            raise ModuleNotFoundError(f"No module named {{spec.name!r}}", name=spec.name)

        def exec_module(self, module):
            pass

    class Hide(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            return importlib.machinery.ModuleSpec(name, Absent()) if name.split(".")[0] in HIDDEN else None

    sys.meta_path.insert(0, Hide())
    import numpy as np
    import abyssal
    from abyssal.runtime import CKF, cli

    rov = abyssal.load("rov4dof")
    ckf = CKF(rov, np.zeros(12), 0.3 * np.eye(12), 1e-3 * np.eye(12), 0.01 * np.eye(4))
    accepted = ckf.step(np.array([20.0, 0.0, 5.0, 0.0]), 0.1, np.zeros(4))
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in HIDDEN)
    code = cli.main(sys.argv[1:])
    print(json.dumps({{"accepted": bool(accepted), "x_finite": bool(np.isfinite(ckf.x).all()), "loaded": loaded,
                      "code": code}}))
""").format(hidden=HIDDEN)


def run_child(tmp_path, *argv):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    proc = subprocess.run([sys.executable, str(script), *argv], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


def test_a_ckf_runs_without_the_extra_and_reproduce_names_the_pip_command(tmp_path):
    result, stderr = run_child(tmp_path, "reproduce", "cn", "--quick", "--runs", "1", "--out", str(tmp_path / "out"))
    assert result["accepted"] and result["x_finite"]
    assert result["loaded"] == []  # importing abyssal and running a filter touched none of them
    assert result["code"] == 2
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("abyssal reproduce: ") and "pip install 'abyssal[experiments]'" in lines[-1], stderr
    assert "Traceback" not in stderr


def test_require_names_the_feature_the_package_and_the_extra(monkeypatch):
    import abyssal.runtime.extras as extras

    assert require("json", "anything") is json
    with pytest.raises(ModuleNotFoundError):  # a module outside the extra is not blamed on it
        require("abyssal_no_such_module", "x")

    def absent(name):
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)

    monkeypatch.setattr(extras.importlib, "import_module", absent)
    with pytest.raises(MissingExtraError, match=r"^the figures needs matplotlib, part of abyssal's experiments extra: "
                                                r"pip install 'abyssal\[experiments\]'$"):
        require("matplotlib.pyplot", "the figures")
    with pytest.raises(MissingExtraError, match=r"needs dask\[distributed\], part of"):
        require("distributed", "a campaign")


def test_verify_skips_a_section_whose_reference_is_absent_and_fails_on_other_errors():
    assert missing_optional(ModuleNotFoundError("x", name="filterpy.kalman")) == \
        "filterpy is not installed (pip install 'abyssal[test]')"
    assert missing_optional(ModuleNotFoundError("x", name="numpy")) is None
    assert missing_optional(ValueError("filterpy")) is None
