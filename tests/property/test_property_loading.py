"""Property-based tests of loading: a name or path that is not a generated model,
and a model folder with a garbage manifest, give a clear error naming what was asked for; never a
crash, a hang, or a bundle."""
from __future__ import annotations

import json

import pytest
from hypothesis import assume, example, given, strategies as st

from abyssal.generated import GeneratedFolderError, available, load

#: what load may raise for something that is not a generated model
REFUSALS = (KeyError, FileNotFoundError, NotADirectoryError, GeneratedFolderError, ValueError, TypeError)

names = st.one_of(
    st.text(min_size=1, max_size=30),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=20),
    st.sampled_from(["..", ".", "/", "~", "rov4dof/..", "../generated", "rov4dof\x00", "/dev/null", "/proc/self",
                     "ROV4DOF", " rov4dof", "rov4dof ", "__pycache__"]),
)


@given(name=names)
def test_load_of_a_name_or_path_that_is_not_a_model_is_refused(name):
    assume(name not in available())
    with pytest.raises(REFUSALS) as info:
        load(name)
    message = str(info.value)
    assert message and ("model" in message or "manifest" in message or "folder" in message or repr(name) in message
                        or name.strip("\x00") in message or "null" in message), f"unclear error {info.value!r}"


@given(value=st.one_of(st.none(), st.integers(), st.floats(), st.binary(max_size=8), st.lists(st.text(max_size=3))))
def test_load_of_a_non_string_is_a_type_error(value):
    with pytest.raises(TypeError):
        load(value)


manifests = st.one_of(
    st.binary(max_size=200),
    st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=10)),
                 lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=8), inner, max_size=3)),
                 max_leaves=8).map(lambda v: json.dumps(v).encode()),
    st.fixed_dictionaries({"model": st.one_of(st.text(max_size=12), st.integers()),
                           "files": st.one_of(st.dictionaries(st.text(max_size=12), st.fixed_dictionaries(
                               {"sha256": st.text(max_size=8)}), max_size=2), st.lists(st.integers(), max_size=2))},
                          ).map(lambda v: json.dumps(v).encode()),
)


@given(manifest=manifests)
@example(manifest=b'{"model": "abc", "files": {}}')  # was: compiled an empty library into the cache, then KeyError 'states'
def test_load_of_a_folder_with_a_garbage_manifest_is_refused(isolated_cache, tmp_path_factory, manifest):
    """(isolated_cache: whatever load does, it never touches the user's cache.)"""
    folder = tmp_path_factory.mktemp("garbage") / "model"
    folder.mkdir()
    (folder / "manifest.json").write_bytes(manifest)
    (folder / "x.c").write_text("int main(void) { return 0; }\n")
    with pytest.raises(REFUSALS) as info:
        load(folder)
    assert str(folder) in str(info.value) or "manifest" in str(info.value), f"unclear error {info.value!r}"
    assert not any(isolated_cache.glob("*/*.so")), "a library was built from a garbage manifest"
