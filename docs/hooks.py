"""MkDocs hook: the command-line reference, generated from the argparse parsers at build time.

A page holding the line ``<!-- cli-reference -->`` gets, in its place, one section per
subcommand of ``selfsupport`` (its one-line help and its ``--help`` text), taken from
:func:`selfsupport.cli.build_parser`, so the reference cannot drift from the parsers.
"""
from __future__ import annotations

import argparse
import os

MARKER = "<!-- cli-reference -->"
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


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (mkdocs hook signature)
    """Replace the marker with the generated reference."""
    if MARKER in markdown:
        markdown = markdown.replace(MARKER, cli_reference())
    return markdown
