"""`abyssal publish NAME --from DIR [--into FILE]`: write a campaign's tables into the marked blocks of the docs.

A number in docs/experiments/*.md is never typed: it sits in a generated block, written from a campaign's tidy CSV
by this module, and the block names the command that made the CSV, the commit it ran and the machine:

    <!-- BEGIN GENERATED: tan/lost-0.1 -->
    <!-- written by `abyssal publish tan --from DIR` from DIR/tan.csv: edit the code, not this block -->
    *From `abyssal reproduce tan --runs 8 --seed 0` at commit 0123456789 (...); CPU, cores, workers, load, wall.*

    | map/track | ... |
    <!-- END GENERATED: tan/lost-0.1 -->

* The key (``tan/lost-0.1``) names the experiment (``EXPERIMENTS`` of reproduce.py) and one of the tables its
  module's ``markdown(rows, config, document) -> {name: markdown}`` makes; ``config`` is the experiment's
  ``Config()`` (``.quick()`` when the command says --quick), ``document`` its <name>.json (the JSON summary with
  the provenance: provenance.py).
* ``publish`` rewrites every block of FILE whose key names the experiment, and refuses (naming them) keys the
  module does not make; tables the module makes that FILE has no block for are listed, not added: where a table
  goes in a page is the page's choice.
* A page's prose cites the numbers of its blocks; tests/scenarios/test_publish.py checks that every block of the
  docs names a command and a commit, and that publishing the small recorded CSVs under tests/data/publish gives the
  committed blocks there, byte for byte (a change of the table code shows as a diff there first).
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

from . import campaign, provenance
from .reproduce import EXPERIMENTS

#: a generated block: its key, its body
BLOCK = re.compile(r"<!-- BEGIN GENERATED: (?P<key>[\w.-]+/[\w.-]+) -->\n(?P<body>.*?)<!-- END GENERATED: (?P=key) -->\n",
                   re.DOTALL)
#: the docs page of each experiment (docs/experiments/<page>.md)
PAGES = {name: experiment.page or name for name, experiment in EXPERIMENTS.items()}
DOCS = provenance.SOURCE_ROOT / "docs" / "experiments"


def markdown_table(header: list[str], rows: list[list[str]], align: str | None = None) -> str:
    """A Markdown (GitHub) table: ``align`` one letter per column, l / r (default: the first left, the rest right)."""
    align = align or "l" + "r" * (len(header) - 1)
    rule = ["---" if a == "l" else "---:" for a in align]
    escape = lambda text: str(text).replace("|", "\\|")  # noqa: E731
    return "\n".join("| " + " | ".join(escape(c) for c in line) + " |" for line in [header, rule, *rows])


def number(value: float, spec: str = ".2f") -> str:
    """A value for a table: '-' for NaN, 'inf' for an infinite one."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return f"{value:{spec}}"


def load_campaign(name: str, folder: Path) -> tuple[list[dict], dict]:
    """(rows of <folder>/<name>.csv, <folder>/<name>.json) of a finished campaign."""
    module = EXPERIMENTS[name].experiment_module()
    columns = campaign.TIDY_COLUMNS[:-1] + tuple(module.EXTRA_COLUMNS) + ("value",)
    rows = campaign.read_csv(Path(folder) / f"{name}.csv", columns)
    document = json.loads((Path(folder) / f"{name}.json").read_text())
    if "provenance" not in document:
        raise ValueError(f"{folder}/{name}.json has no provenance (it predates `abyssal reproduce` recording one): "
                         "rerun the campaign")
    return rows, document


def tables(name: str, rows: list[dict], document: dict) -> dict[str, str]:
    """{table name: markdown} of one experiment's campaign (its module's ``markdown``)."""
    module = EXPERIMENTS[name].experiment_module()
    config = module.Config()
    if document.get("quick"):
        config = config.quick()
    return module.markdown(rows, config, document)


def block(key: str, table: str, record: dict, source: str) -> str:
    """The text of one generated block (module docstring)."""
    name = key.split("/")[0]
    return (f"<!-- BEGIN GENERATED: {key} -->\n"
            f"<!-- written by `abyssal publish {name} --from DIR` from DIR/{Path(source).name}: edit the code, not this "
            f"block -->\n*From {provenance.describe(record)}.*\n\n{table.rstrip()}\n"
            f"<!-- END GENERATED: {key} -->\n")


def publish(name: str, folder: Path, into: Path) -> tuple[list[str], list[str]]:
    """Rewrite the blocks of ``into`` that belong to experiment ``name`` from <folder>/<name>.csv; returns (keys
    written, tables made that ``into`` has no block for). A block whose table the module does not make is refused."""
    rows, document = load_campaign(name, folder)
    made = tables(name, rows, document)
    text = Path(into).read_text()
    keys = [m["key"] for m in BLOCK.finditer(text) if m["key"].split("/")[0] == name]
    unknown = [k for k in keys if k.split("/", 1)[1] not in made]
    if unknown:
        raise ValueError(f"{into}: block(s) {unknown} name tables `{name}` does not make (it makes {sorted(made)})")
    record = document["provenance"]

    def replace(match):
        key = match["key"]
        if key.split("/")[0] != name:
            return match.group(0)
        return block(key, made[key.split("/", 1)[1]], record, f"{name}.csv")

    Path(into).write_text(BLOCK.sub(replace, text))
    return keys, sorted(set(made) - {k.split("/", 1)[1] for k in keys})


def main(args) -> int:
    """`abyssal publish NAME --from DIR [--into FILE]`."""
    into = Path(args.into) if args.into else DOCS / f"{PAGES[args.experiment]}.md"
    written, missing = publish(args.experiment, Path(args.source), into)
    print(f"wrote {len(written)} block(s) of {into}: {', '.join(written) or '-'}")
    if missing:
        print(f"tables with no block in {into.name} (not written): {', '.join(missing)}")
    return 0
