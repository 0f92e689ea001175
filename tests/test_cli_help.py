"""Every command's help is plain text and describes every argument."""

from __future__ import annotations

import argparse

from controller.cli import build_parser


def _parsers(parser: argparse.ArgumentParser, path: str = "heliocal"):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{path} {name}")


def test_help_is_plain_text_and_every_argument_is_described():
    seen = 0
    for path, parser in _parsers(build_parser()):
        text = parser.format_help()
        assert "``" not in text and ":class:" not in text and ":func:" not in text, path
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction) or action.help == argparse.SUPPRESS:
                continue
            assert action.help, f"{path}: {action.option_strings or action.dest} has no help text"
        seen += 1
    assert seen > 20  # every command and sub-command was looked at
