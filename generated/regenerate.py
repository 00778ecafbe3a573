"""Write (or check) the committed C sources of every registered model.

The only place that turns equations into files: `abyssal regenerate` calls ``regenerate()``,
`abyssal regenerate --check` calls ``check()``, which regenerates in memory and reports the
files that differ from what is committed.
"""
from __future__ import annotations

import difflib
from pathlib import Path

GENERATED_DIR = Path(__file__).resolve().parent


def expected_files(models: list[str] | None = None) -> dict[Path, str]:
    """Path (relative to generated/) -> text, for every registered model (or the named ones)."""
    from abyssal.symbolic import codegen
    from abyssal.symbolic.filters import filter_units
    from abyssal.symbolic.models import REGISTRY

    names = list(REGISTRY) if models is None else models
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise KeyError(f"unknown model(s) {unknown}; registered: {sorted(REGISTRY)}")
    out: dict[Path, str] = {}
    for name in names:
        model = REGISTRY[name]()
        units = [codegen.Unit("model", codegen.model_functions(model)), *filter_units(model)]
        source = f"symbolic/models/{name}.py"
        for fname, text in codegen.generate_model(model, units, source).items():
            out[Path(name) / fname] = text
    return out


def regenerate(models: list[str] | None = None) -> list[Path]:
    """Write the generated files; remove stale C files of regenerated models. Returns written paths."""
    files = expected_files(models)
    written = []
    for rel, text in files.items():
        path = GENERATED_DIR / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            written.append(path)
    for folder in {rel.parent for rel in files}:
        for stale in (GENERATED_DIR / folder).glob("*.c"):
            if stale.relative_to(GENERATED_DIR) not in files:
                stale.unlink()
                written.append(stale)
    return written


def check(models: list[str] | None = None) -> list[str]:
    """Problems found (empty when the committed files match the equations)."""
    files = expected_files(models)
    problems = []
    for rel, text in sorted(files.items()):
        path = GENERATED_DIR / rel
        if not path.exists():
            problems.append(f"missing: generated/{rel}")
            continue
        committed = path.read_text()
        if committed != text:
            diff = list(difflib.unified_diff(committed.splitlines(), text.splitlines(), f"committed/{rel}", f"regenerated/{rel}", lineterm="", n=1))
            shown = "\n".join(diff[:40]) + ("\n..." if len(diff) > 40 else "")
            problems.append(f"differs: generated/{rel}\n{shown}")
    for folder in {rel.parent for rel in files}:
        for extra in sorted((GENERATED_DIR / folder).glob("*.c")):
            if extra.relative_to(GENERATED_DIR) not in files:
                problems.append(f"stale: generated/{extra.relative_to(GENERATED_DIR)} is no longer generated")
    return problems
