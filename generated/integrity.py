"""The manifest's own integrity record: a hand-edited manifest is refused, naming the field.

Every source file of a model folder is checked against the sha256 its manifest records; this
module covers the manifest itself. ``seal`` adds an ``integrity`` entry when the manifest is
written: the sha256 of the rest of the manifest (canonical JSON: sorted keys, no spaces) and a short
digest of every top-level field and of each element of a field that is a list or a mapping
(``parameters[3]``, ``functions['cn2d_f']``). ``edits`` gives what differs from that record: an empty
list for an untouched manifest, else the fields that were edited, added or removed (a parameter
default changed from 0.1 to 123 is ``parameters[0] (c)``; a state added to the list is
``states: 3 entries, 2 when written``). The digests guard against accidents (an editor, a merge, a
truncated copy), not against someone who recomputes them.
"""
from __future__ import annotations

import hashlib
import json

#: the manifest key holding the record
KEY = "integrity"


def _canonical(value) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":")).encode("utf-8")


def _digest(value) -> str:
    return hashlib.blake2b(_canonical(value), digest_size=6).hexdigest()


def _fields(manifest: dict) -> dict[str, str]:
    """Digest of every top-level field and of each element of a list or mapping field."""
    out = {}
    for key, value in manifest.items():
        if key == KEY:
            continue
        out[key] = _digest(value)
        if isinstance(value, list):
            out.update({f"{key}[{i}]": _digest(v) for i, v in enumerate(value)})
        elif isinstance(value, dict):
            out.update({f"{key}[{k!r}]": _digest(v) for k, v in value.items()})
    return out


def _record(manifest: dict) -> dict:
    rest = {k: v for k, v in manifest.items() if k != KEY}
    return {"sha256": hashlib.sha256(_canonical(rest)).hexdigest(), "fields": _fields(rest)}


def seal(manifest_text: str) -> str:
    """The manifest (JSON text, as ``codegen.generate_model`` writes it) with its integrity record."""
    manifest = json.loads(manifest_text)
    manifest[KEY] = _record(manifest)
    return json.dumps(manifest, indent=1, sort_keys=True) + "\n"


def _label(key: str, value) -> str:
    name = value.get("name") if isinstance(value, dict) else None
    return f"{key} ({name})" if isinstance(name, str) else key


def edits(manifest: dict) -> list[str]:
    """What differs from the manifest's integrity record ([] when nothing does; see the module docstring)."""
    record = manifest.get(KEY)
    if not (isinstance(record, dict) and isinstance(record.get("sha256"), str) and isinstance(record.get("fields"), dict)):
        return [f"its {KEY!r} record is missing or damaged (written by an older abyssal, or edited)"]
    rest = {k: v for k, v in manifest.items() if k != KEY}
    if hashlib.sha256(_canonical(rest)).hexdigest() == record["sha256"]:
        return []
    written, now = record["fields"], _fields(rest)
    found = []
    for key, value in rest.items():
        if key not in written:
            found.append(f"{key} (added)")
            continue
        if now[key] == written[key]:
            continue
        if isinstance(value, (list, dict)):
            items = list(enumerate(value)) if isinstance(value, list) else list(value.items())
            labels = [f"{key}[{i}]" if isinstance(value, list) else f"{key}[{i!r}]" for i, _ in items]
            before = [label for label in written if label.startswith(key + "[")]
            if isinstance(value, list) and len(before) != len(value):
                found.append(f"{key}: {len(value)} entries, {len(before)} when written")
            found += [_label(label, v) + ("" if label in written else " (added)")
                      for label, (_, v) in zip(labels, items) if written.get(label) != now[label]]
            found += [f"{label} (removed)" for label in before if label not in now]
        else:
            found.append(key)
    found += [f"{key} (removed)" for key in written if "[" not in key and key not in rest]
    return found or ["the manifest differs from its integrity record (sha256)"]
