"""The documentation's code runs: every ```python block of every page in docs/ (mkdocs.yml's site), in order.

A page's blocks run one after another in one namespace, in a working folder of the page's own under one
session-wide temporary folder (what a reader who types the page into a fresh folder would get), so a page whose
code no longer works fails here, naming the page, the block's number and first line. A block whose first line is a
comment naming a Python file (``# myrov.py: ...``) is a file the reader saves: it is written into the working
folder (importable from the next blocks), not run. Blocks that must not run
(shell commands, C, C++, output) use other fences (```bash, ```c, ```cpp, ```text); the one C block, on
on-the-vehicle.md, is built and run against a fresh export by its own test below. The blocks are found with
mktestdocs (the `docs` and `test` extras); the compile cache is the user's, so a page's model compiles once.
A page whose Python reads what a shell command of the page made (replay.md reads the log that
examples/replay_log/make_logs.py writes) names that command in SETUP: it runs first, in the page's folder.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

mktestdocs = pytest.importorskip("mktestdocs", reason="mktestdocs is not installed (pip install -e '.[test]')")

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
#: the shell commands a page's Python depends on, as the page shows them (run from the page's folder)
SETUP = {"replay.md": [[sys.executable, str(REPO / "examples" / "replay_log" / "make_logs.py"), "--out", "demo"]]}
PAGES = sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md"))


#: the first line of a block that is a file to save: "# name.py" (and anything after a colon)
FILE_BLOCK = re.compile(r"#\s*(?P<name>[A-Za-z_][A-Za-z0-9_]*\.py)\s*(:.*)?$")


def python_blocks(page: str) -> list[str]:
    return mktestdocs.grab_code_blocks((DOCS / page).read_text(encoding="utf-8"), lang="python")


RUNNABLE = [page for page in PAGES if python_blocks(page)]


def test_the_pages_have_code_to_run():
    assert "getting-started.md" in RUNNABLE and "own-vehicle.md" in RUNNABLE
    assert set(SETUP) <= set(RUNNABLE)
    for page, commands in SETUP.items():  # the page shows each setup command to its reader
        text = (DOCS / page).read_text("utf-8")
        assert all(f"{Path(c[1]).parent.parent.name}/{Path(c[1]).parent.name}/{Path(c[1]).name}" in text
                   for c in commands), page


def test_no_page_hides_python_in_an_unrun_fence():
    """A block a reader would take for Python is run: ```py, ```python3, ```pycon fences and ```python with more
    words on the fence line (which the runner would pass over) are refused."""
    fence = re.compile(r"^[ \t]*```[ \t]*(py|python3|pycon|ipython|python[ \t]+\S.*)[ \t]*$", re.M)
    hidden = [(page, m.group(0).strip()) for page in PAGES for m in fence.finditer((DOCS / page).read_text("utf-8"))]
    assert not hidden, f"use a plain ```python fence (run by this test) or ```text: {hidden}"


@pytest.mark.parametrize("page", RUNNABLE)
def test_page_code_runs(page, tmp_path_factory, monkeypatch):
    folder = tmp_path_factory.mktemp(re.sub(r"\W", "_", page.removesuffix(".md")))
    monkeypatch.chdir(folder)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.syspath_prepend(str(folder))
    modules = set(sys.modules)
    namespace = {"__name__": "__main__"}
    for command in SETUP.get(page, []):
        done = subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"docs/{page}: the setup {command} failed:\n{done.stdout}\n{done.stderr}"
    try:
        for k, block in enumerate(python_blocks(page), 1):
            first = block.strip().splitlines()[0]
            saved = FILE_BLOCK.match(first)
            if saved:
                (folder / saved["name"]).write_text(block, encoding="utf-8")
                continue
            try:
                exec(compile(block, f"docs/{page} block {k}", "exec"), namespace)
            except Exception as exc:
                raise AssertionError(f"docs/{page}, Python block {k} ({first!r}) failed: {type(exc).__name__}: "
                                     f"{exc}") from exc
    finally:
        for name in set(sys.modules) - modules:  # the page's own files (myrov.py): another page may reuse the name
            if str(getattr(sys.modules[name], "__file__", "") or "").startswith(str(folder)):
                del sys.modules[name]


def test_on_the_vehicle_c_code_builds_and_runs(tmp_path):
    """The C block of on-the-vehicle.md, in a main() with its variables declared, compiles strictly against a fresh
    export of rov4dof and runs: init, a step, a predict_to and a late USBL-style fix fused from the history."""
    import shutil

    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("skipped, because no C compiler (cc, gcc) is on PATH")
    import abyssal

    project = abyssal.export("rov4dof", filter="ckf", out=tmp_path / "rov4dof_ckf", steps=200)
    text = (DOCS / "on-the-vehicle.md").read_text("utf-8")
    (block,) = re.findall(r"```c\n(.*?)```", text, re.S)
    top = [line for line in block.splitlines() if line.startswith(("#include", "static "))]
    body = [line for line in block.splitlines() if line and not line.startswith(("#include", "static "))]
    main = "\n".join([
        "#include <math.h>", "#include <stdio.h>", *top, "int main(void) {",
        "  double x0[12] = {0}, P0[144] = {0}, Q[144] = {0}, R[16] = {0}, t0 = 0.0;",
        "  double tau[4] = {20.0, 5.0, 10.0, 0.5}, z[4] = {0.1, 0.0, 0.05, 0.0}, t = 0.3, t_fix = 0.15;",
        "  double z_fix[4] = {0.1, 0.0, 0.05, NAN}, R_fix[16] = {0};",
        "  for (int i = 0; i < 12; ++i) { P0[13 * i] = 0.3; Q[13 * i] = i < 8 ? 1e-4 : 1e-2; }",
        "  for (int i = 0; i < 4; ++i) { R[5 * i] = 0.05; R_fix[5 * i] = 0.1; }",
        *("  " + line for line in body),
        "  if (code < 0) return 1;",
        "  printf(\"%d %.6f\\n\", code, x[0]);",
        "  return 0;", "}", ""])
    (tmp_path / "main.c").write_text(main, encoding="utf-8")
    sources = sorted(str(p) for p in (project / "src").glob("*.c"))
    binary = tmp_path / "main"
    built = subprocess.run([compiler, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wno-unused-variable", "-O1",
                            f"-I{project / 'include'}", *sources, str(tmp_path / "main.c"), "-o", str(binary), "-lm"],
                           capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, f"docs/on-the-vehicle.md's C does not build:\n{main}\n{built.stderr[-3000:]}"
    ran = subprocess.run([str(binary)], capture_output=True, text=True, timeout=60)
    assert ran.returncode == 0, f"docs/on-the-vehicle.md's C was refused: {ran.stdout}{ran.stderr}"
    assert int(ran.stdout.split()[0]) == 1, ran.stdout  # ABYSSAL_UPDATED: the late fix was fused
