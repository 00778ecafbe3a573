"""abyssal.generated: the committed C of every model, its compile cache and its loader.

    bundle = abyssal.generated.load("rov4dof")
    x1 = bundle.f(x0, tau, None, 0.1)

``load`` reads ``generated/<name>/manifest.json``, checks the committed sources against the
manifest's hashes, compiles them on first use (see build.py) and returns a ModelBundle.
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

from .build import BuildError, CompilerNotFoundError, build
from .bundle import BatchBinding, Binding, CompiledFunction, ModelBundle

GENERATED_DIR = Path(__file__).resolve().parent


def available() -> list[str]:
    """Names of the models with committed generated sources."""
    return sorted(p.parent.name for p in GENERATED_DIR.glob("*/manifest.json"))


def read_sources(name: str) -> tuple[dict, dict[str, str]]:
    folder = GENERATED_DIR / name
    manifest_path = folder / "manifest.json"
    if not manifest_path.is_file():
        raise KeyError(f"no generated model {name!r}; available: {available()} (run `abyssal regenerate` after adding one)")
    manifest = json.loads(manifest_path.read_text())
    sources = {}
    for fname, meta in manifest["files"].items():
        text = (folder / fname).read_text()
        if hashlib.sha256(text.encode()).hexdigest() != meta["sha256"]:
            raise RuntimeError(
                f"generated/{name}/{fname} does not match its manifest (edited by hand?); run `abyssal regenerate`"
            )
        sources[fname] = text
    return manifest, sources


@lru_cache(maxsize=None)
def load(name: str) -> ModelBundle:
    """The compiled bundle of a registered model (compiled on first use, cached per user)."""
    manifest, sources = read_sources(name)
    return ModelBundle(manifest, build(name, sources))


__all__ = [
    "BatchBinding", "Binding", "BuildError", "CompiledFunction", "CompilerNotFoundError", "ModelBundle",
    "available", "load", "read_sources",
]
