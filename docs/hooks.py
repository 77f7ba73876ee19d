"""MkDocs hook: reference text generated from the code at build time, so it cannot drift.

* ``<!-- cli-reference -->`` becomes one section per subcommand of ``selfsupport`` (its one-line
  help and its ``--help`` text), from :func:`selfsupport.cli.build_parser`;
* ``<!-- network-schema -->`` becomes the network format's JSON Schema, as packaged
  (``selfsupport/io/network.schema.json``);
* ``<!-- bench-table1 -->``, ``<!-- bench-dome -->``, ``<!-- bench-destruction -->`` and
  ``<!-- bench-koebe -->`` become the paper's claims beside ours, from the committed
  ``benchmarks/results/*.csv`` (:data:`benchmarks.report.PAPER_TABLES`).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

MARKER = "<!-- cli-reference -->"
SCHEMA_MARKER = "<!-- network-schema -->"
#: the checkout (benchmarks/ is not an installed package)
ROOT = Path(__file__).resolve().parent.parent
#: The width argparse wraps the help to (it reads COLUMNS), fixed so the page does not depend on
#: the terminal the site was built in.
WIDTH = "100"


def cli_reference() -> str:
    """Markdown of every subcommand's help, in the order ``selfsupport --help`` lists them."""
    from selfsupport.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        helps = {c.dest: c.help for c in sub._choices_actions}
        parts = ["```text", parser.format_help().rstrip(), "```", ""]
        for name, p in sub.choices.items():
            parts += [f"## {name} {{#{name}}}", "", f"{helps.get(name, '')}", "",
                      "```text", p.format_help().rstrip(), "```", ""]
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(parts)


def network_schema() -> str:
    """The packaged JSON Schema of the network format, as a fenced block."""
    from importlib.resources import files

    text = files("selfsupport.io").joinpath("network.schema.json").read_text(encoding="utf-8")
    return f"```json\n{text.rstrip()}\n```"


def paper_tables() -> dict:
    """The comparison tables' markers and their generators (:data:`benchmarks.report.PAPER_TABLES`)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from benchmarks.report import PAPER_TABLES

    return PAPER_TABLES


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (mkdocs hook signature)
    """Replace the markers with the generated text."""
    if MARKER in markdown:
        markdown = markdown.replace(MARKER, cli_reference())
    if SCHEMA_MARKER in markdown:
        markdown = markdown.replace(SCHEMA_MARKER, network_schema())
    if "<!-- bench-" in markdown:
        for marker, table in paper_tables().items():
            if marker in markdown:
                markdown = markdown.replace(marker, table())
    return markdown
