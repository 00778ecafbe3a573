"""abyssal.generated: the committed C of every model, its compile cache and its loader.

    bundle = abyssal.generated.load("rov4dof")          # a built-in model
    mine = abyssal.generated.load("gen/myvessel")        # a folder written by abyssal.generate
    x1 = bundle.f(x0, tau, None, 0.1)

``load`` reads ``<folder>/manifest.json``, checks it against its own integrity record (integrity.py:
a hand-edited manifest is refused, naming the field) and every source against the manifest's sha256
(a hand-edited, truncated or missing file is refused, naming the file), compiles the folder's sources
(its generated C and its copy of the descriptor's type, abyssal_model.h) on first use through the
shared per-user cache (see build.py) and returns a ModelBundle. The filters' C runtime is not here: it
is abyssal.runtime's (runtime/c), compiled once into its own library, and reaches the model through
the descriptor ``<m>_descriptor`` of this library. The cache entry is named by the manifest's model name (a checked C
identifier), never by the path given.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import threading
from pathlib import Path

from . import integrity
from .build import BuildError, CompilerNotFoundError, build
from .bundle import BatchBinding, Binding, CompiledFunction, ModelBundle

GENERATED_DIR = Path(__file__).resolve().parent


class GeneratedFolderError(RuntimeError):
    """A generated folder that cannot be trusted: bad manifest, or a source that does not match it."""


def available() -> list[str]:
    """Names of the built-in models with committed generated sources."""
    return sorted(p.parent.name for p in GENERATED_DIR.glob("*/manifest.json"))


def _looks_like_path(name) -> bool:
    return isinstance(name, os.PathLike) or any(sep in name for sep in ("/", os.sep)) or name.startswith(("~", "."))


def _exists(path: Path, kind: str) -> bool:
    """path.is_file() / is_dir(), False where the system cannot even look (a name too long, a NUL byte)."""
    try:
        return path.is_file() if kind == "file" else path.is_dir()
    except (OSError, ValueError):
        return False


def model_folder(name_or_path) -> Path:
    """The folder of a built-in name, or of a path to a folder written by ``abyssal.generate``."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"load() takes a model name or a folder path, got {type(name_or_path).__name__}")
    if not _looks_like_path(name_or_path) and _exists(GENERATED_DIR / name_or_path / "manifest.json", "file"):
        return GENERATED_DIR / name_or_path
    try:
        folder = Path(name_or_path).expanduser()
    except RuntimeError as exc:  # '~user' with no such user or home directory
        raise FileNotFoundError(f"{name_or_path!r}: cannot expand the home directory ({exc})") from None
    if not _looks_like_path(name_or_path) and not _exists(folder, "dir"):
        shown = name_or_path if len(name_or_path) <= 80 else name_or_path[:60] + f"... ({len(name_or_path)} characters)"
        raise KeyError(f"no generated model {shown!r}; available: {available()} (run `abyssal regenerate` after "
                       "adding one, or give the path of a folder written by abyssal.generate / "
                       "`abyssal regenerate --model ... --out DIR`)")
    if not _exists(folder, "dir"):
        raise FileNotFoundError(f"{folder}: no such folder (expected a model folder written by abyssal.generate)")
    if not (folder / "manifest.json").is_file():
        inside = sorted(p.parent.name for p in folder.glob("*/manifest.json"))
        hint = f"it holds generated models {inside}: load {folder / inside[0]}" if inside else (
            "generate one with `abyssal regenerate --model FILE.py:FUNCTION --out DIR`")
        raise FileNotFoundError(f"{folder} has no manifest.json; {hint}")
    return folder.resolve()


def read_folder(folder: Path) -> tuple[dict, dict[str, str]]:
    """(manifest, file name -> text) of a model folder, every file checked against the manifest."""
    path = folder / "manifest.json"
    try:
        manifest = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as exc:
        raise GeneratedFolderError(f"{path} is not a valid abyssal manifest (truncated or edited by hand?): {exc}") from exc
    problem = manifest_problem(manifest)
    if problem:
        raise GeneratedFolderError(f"{path} is not a valid abyssal manifest (truncated or edited by hand?): {problem}")
    files = manifest["files"]
    generated_by = manifest.get("generated_by")
    regenerate_with = generated_by.get("command", "abyssal regenerate") if isinstance(generated_by, dict) else "abyssal regenerate"
    if integrity.KEY not in manifest:
        raise GeneratedFolderError(f"{path} has no {integrity.KEY!r} record (written by an older abyssal, or its record "
                                   f"was deleted), so it cannot be checked; run `{regenerate_with}`")
    edited = integrity.edits(manifest)
    if edited:
        raise GeneratedFolderError(f"{path} was edited after abyssal wrote it ({'; '.join(edited[:6])}"
                                   f"{'; ...' if len(edited) > 6 else ''}): a hand-edited manifest is refused; run "
                                   f"`{regenerate_with}`")
    sources = {}
    for fname, meta in files.items():
        try:
            data = (folder / fname).read_bytes()
        except FileNotFoundError:
            raise GeneratedFolderError(f"{folder / fname} is listed in the manifest but missing; run `{regenerate_with}`") from None
        if hashlib.sha256(data).hexdigest() != meta["sha256"]:
            raise GeneratedFolderError(
                f"{folder / fname} does not match its manifest (edited by hand or truncated: {len(data)} bytes, the "
                f"manifest says {meta.get('bytes')}); run `{regenerate_with}`"
            )
        sources[fname] = data.decode()
    return manifest, sources


_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_REQUIRED_FUNCTIONS = ("f", "F", "h", "H")
#: the descriptor's type, copied into every folder by the code generator (abyssal.symbolic.codegen.MODEL_HEADER)
MODEL_HEADER = "abyssal_model.h"


def manifest_problem(manifest) -> str | None:
    """What makes `manifest` unusable (checked before anything is compiled), or None."""
    if not isinstance(manifest, dict):
        return f"expected a JSON object, got {type(manifest).__name__}"
    model = manifest.get("model")
    if not (isinstance(model, str) and _IDENTIFIER.match(model)):
        return f"model name {model!r} is not a C identifier"
    for key in ("states", "inputs", "parameters", "noises", "outputs"):
        entries = manifest.get(key)
        if not isinstance(entries, list) or not all(isinstance(q, dict) and isinstance(q.get("name"), str) for q in entries):
            return f"{key!r} must be a list of named quantities"
    if not all(isinstance(q.get("default"), (int, float)) and not isinstance(q.get("default"), bool)
               for q in manifest["parameters"]):
        return "every parameter needs a numeric default"
    for key, n in (("angle_outputs", len(manifest["outputs"])), ("angle_states", len(manifest["states"]))):
        indices = manifest.get(key, [])
        if not isinstance(indices, list) or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < n
                                                    for i in indices):
            return f"{key!r} must list indices in 0..{n - 1}"
    if manifest.get("discretisation") not in ("rk4", "euler", "discrete"):
        return f"unknown discretisation {manifest.get('discretisation')!r}"
    files = manifest.get("files")
    if not isinstance(files, dict) or not files:
        return "'files' must map file names to their sha256"
    for fname, meta in files.items():
        if not (fname.endswith((".c", ".h")) and Path(fname).name == fname and not fname.startswith(".")):
            return f"{fname!r} is not a plain C file name of this folder"
        if not (isinstance(meta, dict) and isinstance(meta.get("sha256"), str)):
            return f"{fname!r} has no sha256"
    functions = manifest.get("functions")
    if not isinstance(functions, dict):
        return "'functions' must describe the generated functions"
    missing = [s for s in _REQUIRED_FUNCTIONS if f"{model}_{s}" not in functions]
    if missing:
        return f"the model functions {missing} are not listed"
    if f"{model}_descriptor.c" in files and MODEL_HEADER not in files:
        return (f"it has a descriptor but no copy of its type {MODEL_HEADER} (written by an older abyssal): "
                "regenerate the folder")
    for name, spec in functions.items():
        if not (isinstance(spec, dict) and spec.get("file") in files and isinstance(spec.get("inputs"), list)
                and isinstance(spec.get("outputs"), list) and name.startswith(model + "_") and _IDENTIFIER.match(name)):
            return f"function {name!r} is not described by a file of this folder, its inputs and outputs"
    return None


def read_sources(name_or_path) -> tuple[dict, dict[str, str]]:
    """(manifest, sources) of a built-in name or a model folder (see ``load``)."""
    return read_folder(model_folder(name_or_path))


_BUNDLES: dict[tuple, ModelBundle] = {}
_LOCK = threading.Lock()


def _fingerprint(folder: Path) -> tuple:
    """Changes whenever a file of the folder does: a stale bundle is never returned after regenerating."""
    return tuple((p.name, st.st_mtime_ns, st.st_size) for p in sorted(folder.iterdir())
                 if p.is_file() for st in [p.stat()])


def load(name_or_path) -> ModelBundle:
    """The compiled bundle of a built-in model name, or of a folder written by ``abyssal.generate``.

    Compiled on first use and cached per user; the same object is returned while the folder's
    files are unchanged.
    """
    folder = model_folder(name_or_path)
    key = (str(folder), _fingerprint(folder))
    with _LOCK:
        bundle = _BUNDLES.get(key)
        if bundle is None:
            manifest, sources = read_folder(folder)
            bundle = ModelBundle(manifest, build(manifest["model"], sources))
            bundle.folder = folder
            _BUNDLES[key] = bundle
    return bundle


__all__ = [
    "BatchBinding", "Binding", "BuildError", "CompiledFunction", "CompilerNotFoundError", "GeneratedFolderError",
    "ModelBundle", "available", "load", "model_folder", "read_folder", "read_sources",
]
