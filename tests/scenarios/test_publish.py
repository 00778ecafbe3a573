"""The docs' numbers are made by the commands they name (runtime/experiments/publish.py).

* Every generated block of docs/experiments/*.md names the campaign command (`abyssal reproduce NAME ...`, NAME the
  block's experiment), the commit it ran at (from a clean tree) and the machine, and each table it holds is one
  the experiment's ``markdown`` makes.
* The recorded campaigns under tests/data/publish (short --quick runs: their CSV and the JSON's provenance) publish
  into exactly the blocks committed in tests/data/publish/<page>.md: a change of the table code shows as a diff here
  first (then rewrite those pages with `abyssal publish NAME --from tests/data/publish --into
  tests/data/publish/<page>.md` and read the diff).
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from abyssal.runtime.experiments import publish

DATA = Path(__file__).resolve().parents[1] / "data" / "publish"
DOCS = Path(__file__).resolve().parents[2] / "docs" / "experiments"
#: the line a block opens with after its comment: "*From `abyssal reproduce NAME ...` at commit <hex>; ..."
SOURCE = re.compile(r"^\*From `abyssal reproduce (?P<name>[\w-]+)(?: [^`]*)?` at commit (?P<commit>[0-9a-f]{10})"
                    r"(?P<dirty> \(uncommitted changes\))?; (?P<machine>[^*]+)\.\*$", re.MULTILINE)


def _blocks(path: Path) -> list[tuple[str, str]]:
    return [(m["key"], m["body"]) for m in publish.BLOCK.finditer(path.read_text())]


@pytest.fixture(scope="module")
def made() -> dict[str, set[str]]:
    """{experiment: the tables its markdown makes} from the recorded campaigns."""
    out = {}
    for name in publish.PAGES:
        rows, document = publish.load_campaign(name, DATA)
        out[name] = set(publish.tables(name, rows, document))
    return out


def test_every_docs_block_names_its_command_commit_and_machine(made):
    pages = sorted(DOCS.glob("*.md"))
    assert {p.stem for p in pages} >= set(publish.PAGES.values())
    keys = []
    for page in pages:
        blocks = _blocks(page)
        text = page.read_text()
        assert text.count("<!-- BEGIN GENERATED") == len(blocks), f"{page.name}: an unclosed or malformed block"
        for key, body in blocks:
            name, table = key.split("/", 1)
            assert name in publish.PAGES and publish.PAGES[name] == page.stem, (page.name, key)
            # a table the recorded (--quick) campaign makes, or one of its family for a case only the full campaign
            # runs (lost-0.15 beside lost-0.1, ape-collinear beside ape-crossing60)
            family = {m.rsplit("-", 1)[0] for m in made[name] if "-" in m}
            assert table in made[name] or table.rsplit("-", 1)[0] in family, (page.name, key, sorted(made[name]))
            source = SOURCE.search(body)
            assert source, f"{page.name} {key}: no '*From `abyssal reproduce ...` at commit ...' line"
            assert source["name"] == name and not source["dirty"], (page.name, key, source.group(0))
            assert "cores" in source["machine"] and "load" in source["machine"], (page.name, key)
            assert "|" in body, f"{page.name} {key}: no table"
            keys.append(key)
    assert len(keys) == len(set(keys)), "a table published twice"


@pytest.mark.parametrize("name", sorted(publish.PAGES))
def test_the_recorded_campaigns_publish_into_the_committed_blocks(name, tmp_path):
    """Emptied blocks of the recorded page are written again, byte for byte; the other experiment's blocks of the
    same page stay as they are."""
    page = DATA / f"{publish.PAGES[name]}.md"
    expected = page.read_text()
    emptied = publish.BLOCK.sub(lambda m: (f"<!-- BEGIN GENERATED: {m['key']} -->\n<!-- END GENERATED: {m['key']} -->\n"
                                           if m["key"].split("/")[0] == name else m.group(0)), expected)
    assert emptied != expected
    target = tmp_path / page.name
    target.write_text(emptied)
    written, missing = publish.publish(name, DATA, target)
    assert target.read_text() == expected
    assert written and not missing  # the recorded page holds every table the experiment makes


def test_publish_refuses_a_block_of_a_table_the_experiment_does_not_make(tmp_path):
    target = tmp_path / "page.md"
    target.write_text("text\n<!-- BEGIN GENERATED: tan/no-such-table -->\n<!-- END GENERATED: tan/no-such-table -->\n")
    with pytest.raises(ValueError, match="no-such-table"):
        publish.publish("tan", DATA, target)


def test_a_campaign_without_provenance_is_refused(tmp_path):
    for suffix in (".csv", ".json"):
        shutil.copy(DATA / f"tan-survey{suffix}", tmp_path / f"tan-survey{suffix}")
    text = (tmp_path / "tan-survey.json").read_text()
    (tmp_path / "tan-survey.json").write_text(text.replace('"provenance"', '"elsewhere"'))
    with pytest.raises(ValueError, match="no provenance"):
        publish.load_campaign("tan-survey", tmp_path)
