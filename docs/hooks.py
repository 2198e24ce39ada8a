"""MkDocs hook: ``<!-- agentax-help: COMMAND [SUB] -->`` in a page becomes that command's --help.

The CLI reference (cli.md) is thus generated from the parsers themselves at build time, in-process
(no subprocess per command), so it cannot drift from the code.
"""

from __future__ import annotations

import contextlib
import io
import os
import re

MARKER = re.compile(r"<!-- agentax-help: ([a-z -]+?) -->")


def command_help(args: list[str]) -> str:
    from agentax.cli import main

    os.environ["COLUMNS"] = "100"
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        try:
            main([*args, "--help"])
        except SystemExit:
            pass
    text = buffer.getvalue().rstrip()
    if not text:
        raise RuntimeError(f"agentax {' '.join(args)} --help printed nothing")
    return text


def on_page_markdown(markdown: str, page, config, files) -> str:
    return MARKER.sub(lambda m: f"```text\n{command_help(m.group(1).split())}\n```", markdown)
