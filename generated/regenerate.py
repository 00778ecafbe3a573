"""Write (or check) generated C: the built-in models, and any Model into a user's folder.

The only place that turns equations into files.

Built-ins (``symbolic/models``): `abyssal regenerate [NAME...]` calls ``regenerate()``,
`abyssal regenerate --check` calls ``check()``, which regenerates in memory and reports the files
that differ from what is committed. Built-ins are written into a source checkout only: on an
installed (non-editable) abyssal, ``regenerate()`` refuses and writes nothing (pip owns those
files, and the next upgrade would silently undo an edit).

A user's model (any Model, no registry): ``generate(model, out_dir)`` writes
``<out_dir>/<model.name>/`` (C, SoA kernels, manifest.json) and ``check_folder`` reports drift;
`abyssal regenerate --model FILE.py:FUNCTION --out DIR [--check]` calls them through
``load_model_spec``. The banner of every file names the command that wrote it, and the manifest
records how to find the model function again (a path relative to the model folder, or a module),
so `abyssal verify DIR/name` can compare the compiled C with CasADi's evaluation of the Model.
"""
from __future__ import annotations

import difflib
import hashlib
import importlib
import inspect
import os
import shlex
import sys
import types
from pathlib import Path

from . import integrity

GENERATED_DIR = Path(__file__).resolve().parent
#: the folder holding the package's three layer folders in a source checkout (symbolic/, generated/, runtime/)
SOURCE_ROOT = GENERATED_DIR.parent


class NotASourceCheckout(RuntimeError):
    """Built-in models can only be regenerated into a source checkout (an editable install)."""


def is_source_checkout() -> bool:
    """True when generated/ sits in a clone (next to pyproject.toml and symbolic/models/), not in site-packages."""
    return (SOURCE_ROOT / "pyproject.toml").is_file() and (SOURCE_ROOT / "symbolic" / "models").is_dir()


def _installed_package_folders() -> list[Path]:
    import abyssal
    import abyssal.runtime
    import abyssal.symbolic

    return [Path(mod.__file__).resolve().parent for mod in (abyssal, abyssal.symbolic, abyssal.runtime)] + [GENERATED_DIR]


# --------------------------------------------------------------------------- one model -> files
def model_files(model, origin=None) -> dict[str, str]:
    """File name -> text of one model folder (see codegen.generate_model): the model's f, F, G, each sensor's h and
    H, the SoA kernels and the descriptor; the model's own further functions (``Model.functions``, e.g. tan3dof's
    fuzzy logic) go into ``<name>_functions.c``. Every filter's algebra is the C runtime's: nothing per filter."""
    from abyssal.symbolic import codegen

    origin = origin or codegen.Origin(command="abyssal.generate()", check="abyssal.check_generated()",
                                      source=f"a Model object named {model.name!r}")
    units = [codegen.Unit("model", codegen.model_functions(model))]
    generated = {fn.name() for unit in units for fn in unit.functions} | {f"{model.name}_descriptor"}
    clashes = sorted(fn.name() for fn in model.functions if fn.name() in generated)
    if clashes:
        raise ValueError(f"model {model.name!r}: functions {clashes} have the names of generated model functions; "
                         "rename them")
    if model.functions:
        units.append(codegen.Unit("functions", model.functions))
    files = codegen.generate_model(model, units, origin)
    files["manifest.json"] = integrity.seal(files["manifest.json"])  # load refuses a manifest edited after this
    return files


def _write(folder: Path, files: dict[str, str]) -> list[Path]:
    """Write changed files into folder; remove C files of this folder that are no longer generated."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for fname, text in files.items():
        path = folder / fname
        if not path.exists() or path.read_text() != text:
            tmp = path.with_name(f".{fname}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)  # never a half-written file under the real name
            written.append(path)
    for stale in folder.glob("*.c"):
        if stale.name not in files:
            stale.unlink()
            written.append(stale)
    return written


def _problems(folder: Path, files: dict[str, str], label: str) -> list[str]:
    """Differences between the files on disk and `files` (label prefixes the reported paths)."""
    problems = []
    for fname, text in sorted(files.items()):
        path = folder / fname
        if not path.exists():
            problems.append(f"missing: {label}/{fname}")
            continue
        committed = path.read_text()
        if committed != text:
            diff = list(difflib.unified_diff(committed.splitlines(), text.splitlines(), f"committed/{fname}",
                                             f"regenerated/{fname}", lineterm="", n=1))
            shown = "\n".join(diff[:40]) + ("\n..." if len(diff) > 40 else "")
            problems.append(f"differs: {label}/{fname}\n{shown}")
    if folder.is_dir():
        for extra in sorted(folder.glob("*.c")):
            if extra.name not in files:
                problems.append(f"stale: {label}/{extra.name} is no longer generated")
    return problems


# --------------------------------------------------------------------------- built-in models
def expected_files(models: list[str] | None = None) -> dict[Path, str]:
    """Path (relative to generated/) -> text, for every registered model (or the named ones)."""
    from abyssal.symbolic import codegen
    from abyssal.symbolic.models import REGISTRY

    names = list(REGISTRY) if models is None else models
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise KeyError(f"unknown model(s) {unknown}; registered: {sorted(REGISTRY)} (for your own model: "
                       "abyssal regenerate --model FILE.py:FUNCTION --out DIR)")
    out: dict[Path, str] = {}
    for name in names:
        origin = codegen.Origin(source=f"symbolic/models/{name}.py")
        model = REGISTRY[name]()
        for fname, text in model_files(model, origin).items():
            out[Path(name) / fname] = text
    return out


def regenerate(models: list[str] | None = None) -> list[Path]:
    """Write the generated files of the built-ins; remove stale C files. Returns written paths."""
    if not is_source_checkout():
        raise NotASourceCheckout(
            f"abyssal is installed at {SOURCE_ROOT} (not a source checkout): built-in models are regenerated into a "
            "clone only (git clone ... && pip install -e .), so nothing was written. For your own model use "
            "`abyssal regenerate --model FILE.py:FUNCTION --out DIR`."
        )
    files = expected_files(models)
    written = []
    for folder in sorted({rel.parent for rel in files}):
        written += _write(GENERATED_DIR / folder, {rel.name: text for rel, text in files.items() if rel.parent == folder})
    return written


def check(models: list[str] | None = None) -> list[str]:
    """Problems found (empty when the committed files match the equations)."""
    files = expected_files(models)
    problems = []
    for folder in sorted({rel.parent for rel in files}):
        problems += _problems(GENERATED_DIR / folder, {rel.name: text for rel, text in files.items() if rel.parent == folder},
                              f"generated/{folder}")
    return problems


# --------------------------------------------------------------------------- a user's model
def load_model_spec(spec: str):
    """(Model, where) from ``path/to/file.py:function`` or ``package.module:function``.

    ``where`` is ("file", absolute path) or ("module", module name). The function is called with no
    arguments and must return a Model (a Model object at that name is taken as is).
    """
    from abyssal.symbolic.model import Model

    target, sep, attr = spec.rpartition(":")
    if not sep or not target or not attr.isidentifier():
        raise ValueError(f"--model {spec!r}: expected FILE.py:FUNCTION (e.g. myvessel.py:myvessel) or MODULE:FUNCTION")
    if target.endswith(".py") or os.sep in target or "/" in target:
        path = Path(target).resolve()
        if not path.is_file():
            raise FileNotFoundError(f"--model {spec!r}: no file {path}")
        name = "abyssal_user_model_" + hashlib.sha256(str(path).encode()).hexdigest()[:12]
        module = types.ModuleType(name)
        module.__file__ = str(path)
        sys.modules[name] = module  # as `import` does: dataclasses and pickling look the module up there
        try:
            # compiled from the file's current text, never from a cached .pyc: a model file edited twice within
            # one second with the same size (e.g. a coefficient 23.8 -> 24.0 and back) would otherwise be stale
            exec(compile(path.read_bytes(), str(path), "exec"), module.__dict__)
        except BaseException:
            del sys.modules[name]
            raise
        where = ("file", str(path))
    else:
        try:
            module = importlib.import_module(target)
        except ModuleNotFoundError as exc:
            raise ValueError(f"--model {spec!r}: cannot import module {target!r} ({exc}); give a file path "
                             "(FILE.py:FUNCTION) or make the module importable") from exc
        where = ("module", target)
    if not hasattr(module, attr):
        raise ValueError(f"--model {spec!r}: {target} has no {attr!r}")
    obj = getattr(module, attr)
    model = obj() if callable(obj) and not isinstance(obj, Model) else obj
    if not isinstance(model, Model):
        raise ValueError(f"--model {spec!r}: {attr} returned {type(model).__name__}, not an abyssal Model")
    return model, where


def _model_function(where, folder: Path) -> tuple[tuple[str, str], ...]:
    """How to find the model again from its folder: a path relative to it, or a module name."""
    kind, value, function = where
    if kind == "file":
        return (("file", Path(os.path.relpath(value, folder.resolve())).as_posix()), ("function", function))
    return (("module", value), ("function", function))


def cli_origin(spec: str, out_dir: str, model_name: str, where) -> "object":
    """The Origin of `abyssal regenerate --model SPEC --out DIR`: the banner names exactly that command."""
    from abyssal.symbolic import codegen

    command = f"abyssal regenerate --model {shlex.quote(spec)} --out {shlex.quote(str(out_dir))}"
    folder = Path(out_dir) / model_name
    return codegen.Origin(command=command, check=command + " --check", source=spec,
                          model_function=_model_function((*where, spec.rpartition(":")[2]), folder))


def _resolve_model(model, out_dir):
    """(Model, Origin) from a Model or a function returning one (whose file is then recorded)."""
    from abyssal.symbolic import codegen
    from abyssal.symbolic.model import Model

    if isinstance(model, Model):
        return model, None
    if not callable(model):
        raise TypeError(f"generate() takes a Model or a function returning one, got {type(model).__name__}")
    built = model()
    if not isinstance(built, Model):
        raise TypeError(f"{getattr(model, '__name__', model)!r} returned {type(built).__name__}, not an abyssal Model")
    try:
        file = inspect.getsourcefile(model)
    except TypeError:
        file = None
    if not file:
        return built, None
    where = ("file", str(Path(file).resolve()), model.__name__)
    origin = codegen.Origin(command="abyssal.generate()", check="abyssal.check_generated()",
                            source=f"{Path(file).name}:{model.__name__}",
                            model_function=_model_function(where, Path(out_dir) / built.name))
    return built, origin


def _user_folder(out_dir, name: str) -> Path:
    folder = Path(out_dir).expanduser().resolve() / name
    if folder.is_relative_to(GENERATED_DIR):
        raise ValueError(f"{out_dir}: generated/ holds the built-in models (written by `abyssal regenerate`); "
                         "generate your own model into a folder of your project")
    if not is_source_checkout():
        for package in _installed_package_folders():
            if folder.is_relative_to(package):
                raise ValueError(f"{out_dir} is inside the installed abyssal package ({package}); the installed package "
                                 "is never written to: choose a folder of your project")
    if folder.exists() and any(folder.iterdir()) and not (folder / "manifest.json").is_file():
        raise FileExistsError(f"{folder} exists and holds files abyssal did not write (no manifest.json): "
                              "choose another --out folder")
    return folder


def generate(model, out_dir, *, origin=None) -> Path:
    """Write ``<out_dir>/<model.name>/`` (C, SoA kernels, manifest) and return that folder.

    model: a Model, or a function returning one (its file is then recorded, so `abyssal verify`
    can compare the compiled C with CasADi). Every filter runs on what is written (the C runtime
    holds their algebra). Files that did not change are not rewritten (their compiled library stays
    cached); C files no longer generated are removed.
    """
    built, derived = _resolve_model(model, out_dir)
    folder = _user_folder(out_dir, built.name)
    _write(folder, model_files(built, origin or derived))
    return folder


def check_folder(model, out_dir, *, origin=None) -> list[str]:
    """Drift of ``<out_dir>/<model.name>/`` against the model (empty when up to date)."""
    built, derived = _resolve_model(model, out_dir)
    folder = Path(out_dir).expanduser().resolve() / built.name
    if not (folder / "manifest.json").is_file():
        return [f"missing: {folder} has no manifest.json (not generated yet)"]
    return _problems(folder, model_files(built, origin or derived), str(Path(out_dir) / built.name))
