"""The README is the site's front page: it fits on a screen, its links resolve, its two commands are CI's, its
example runs; the design page's layout names only paths that exist (so it agrees with the tree)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def test_readme_fits_on_a_screen():
    lines = README.read_text("utf-8").splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines; the longer texts belong in docs/"


def test_readme_links_resolve():
    broken = []
    for target in LINK.findall(README.read_text("utf-8")):
        if re.match(r"[a-z]+:", target):  # http(s), mailto: not checked offline
            continue
        path, _, anchor = target.partition("#")
        if not (REPO / path).exists():
            broken.append(target)
    assert not broken, f"README.md links to missing files: {broken}"


def test_readme_commands_are_the_ones_ci_runs():
    """The two commands at the top: the install (with the extras .ci/run installs) and the test command."""
    text = README.read_text("utf-8")
    first = re.search(r"```bash\n(.*?)\n(.*?)\n```", text, re.S)
    assert first and text.index(first.group(0)) < 600, "the two commands come first"
    install, test = first.group(1), first.group(2)
    ci = (REPO / ".ci" / "run").read_text("utf-8")
    extras = re.search(r"pip install --quiet -e '(\.\[[^\]]+\])'", ci).group(1)
    assert f"pip install -e '{extras}'" in install and "abyssal verify" in install and "abyssal verify" in ci
    assert test.strip() == "python -m pytest -q" and "python -m pytest -q" in ci


def test_readme_example_runs(tmp_path, monkeypatch):
    mktestdocs = pytest.importorskip("mktestdocs", reason="mktestdocs is not installed (pip install -e '.[test]')")
    monkeypatch.chdir(tmp_path)
    blocks = mktestdocs.grab_code_blocks(README.read_text("utf-8"), lang="python")
    assert blocks
    namespace = {"__name__": "__main__"}
    for k, block in enumerate(blocks, 1):
        exec(compile(block, f"README.md block {k}", "exec"), namespace)


def test_design_layout_names_existing_paths():
    text = (REPO / "docs" / "design.md").read_text("utf-8")
    section = text[text.index("## Layout"):text.index("## Where to add things")]
    block = re.search(r"```text\n(.*?)```", section, re.S).group(1)
    paths = [line.split()[0] for line in block.splitlines() if line and not line[0].isspace()]
    assert len(paths) > 30
    missing = [p for p in paths if not (REPO / p).exists()]
    assert not missing, f"docs/design.md's layout names paths that are not in the tree: {missing}"
    # every top-level folder of the package's layers and every runtime subpackage is named
    for layer in ("symbolic", "generated", "runtime", "verify"):
        assert f"{layer}/" in paths
    for sub in sorted(p.name for p in (REPO / "runtime").iterdir() if p.is_dir() and p.name != "__pycache__"):
        assert any(p.startswith(f"runtime/{sub}") for p in paths), f"runtime/{sub}/ is not in docs/design.md's layout"
