"""MkDocs hooks: the package laid out for the API reference, and the figures the pages show from examples/.

The package. abyssal's subpackages install from other folders (pyproject's package-dir: abyssal.symbolic is symbolic/,
abyssal.generated generated/, abyssal.runtime runtime/, abyssal.verify verify/), so abyssal/ on disk holds
neither of them and griffe, which finds submodules by walking the package's folder, cannot reach
`abyssal.symbolic.fossen`. This hook builds build/docs-packages/abyssal/: symbolic links to abyssal/'s own files
and to the four subpackages' folders, the layout an installed wheel has; mkdocs.yml points the Python handler's
`paths` at it. Nothing is copied: the reference is read from the sources as they are.

The figures. A page shows a figure an example writes (examples/auv_navigation/auv_navigation.png) as
``figures/<name>``; FIGURES maps each to the example's file, which the site serves as it is in the repository (no
copy in docs/ to go stale). A missing figure fails the build.
"""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREE = ROOT / "build" / "docs-packages" / "abyssal"
FIGURES = {"figures/auv_navigation.png": "examples/auv_navigation/auv_navigation.png"}
SUBPACKAGES = {"symbolic": "symbolic", "generated": "generated", "runtime": "runtime", "verify": "verify"}


def _link(link: Path, target: Path) -> None:
    if link.is_symlink() or link.exists():
        if link.is_symlink() and link.resolve() == target.resolve():
            return
        link.unlink()
    link.symlink_to(target, target_is_directory=target.is_dir())


def layout() -> Path:
    TREE.mkdir(parents=True, exist_ok=True)
    wanted = {entry.name: entry for entry in (ROOT / "abyssal").iterdir() if entry.name != "__pycache__"}
    wanted.update({name: ROOT / folder for name, folder in SUBPACKAGES.items()})
    for stale in TREE.iterdir():
        if stale.name not in wanted:
            stale.unlink()
    for name, target in wanted.items():
        _link(TREE / name, target)
    return TREE.parent


layout()  # at import: before mkdocstrings' handler reads its search paths


def on_startup(command, dirty):  # noqa: ARG001 (MkDocs' hook signature)
    layout()


def on_files(files, config):
    from mkdocs.structure.files import File

    for uri, source in FIGURES.items():
        path = ROOT / source
        if not path.is_file():
            raise FileNotFoundError(f"docs/hooks.py: {source} (shown as {uri}) is missing")
        files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files
