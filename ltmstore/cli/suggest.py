"""Suggestions for misspelt options, commands and choices: ``did you mean --lattice?``."""

from __future__ import annotations

import argparse
import difflib
import re

_CHOICE = re.compile(r"invalid choice: '(?P<value>[^']*)' \(choose from (?P<choices>.*)\)$")


def command_parser(parser: argparse.ArgumentParser,
                   namespace: argparse.Namespace) -> argparse.ArgumentParser:
    """The (sub-)parser whose command ``namespace`` names, following nested sub-commands
    (``ltm archive run``); ``parser`` itself when it has none."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen = action.choices.get(getattr(namespace, action.dest, None) or "")
            if chosen is not None:
                return command_parser(chosen, namespace)
    return parser


def option_strings(parser: argparse.ArgumentParser) -> list[str]:
    """Every ``--long`` option of ``parser``."""
    return [s for action in parser._actions for s in action.option_strings
            if s.startswith("--")]


def closest(word: str, known: list[str]) -> str | None:
    """The entry of ``known`` closest to ``word`` (compared without leading dashes), if any is
    close."""
    names = {k.lstrip("-"): k for k in known}
    close = difflib.get_close_matches(word.lstrip("-"), list(names), n=1, cutoff=0.7)
    return names[close[0]] if close else None


def unrecognized(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """The error message for arguments ``parser`` does not know, with the closest option for
    each misspelt one (``--latice`` -> ``did you mean --lattice?``)."""
    known = option_strings(parser)
    pairs = [(arg, closest(arg, known)) for arg in
             (e.split("=", 1)[0] for e in extras if e.startswith("--"))]
    pairs = [(arg, close) for arg, close in pairs if close]
    message = f"unrecognized arguments: {' '.join(extras)}"
    if len(pairs) == 1:
        return f"{message}; did you mean {pairs[0][1]}?"
    if pairs:
        return f"{message}; did you mean " + ", ".join(
            f"{close} instead of {arg}" for arg, close in pairs) + "?"
    return message


def misspelt_hint(parser: argparse.ArgumentParser, message: str, given: list[str]) -> str:
    """``; did you mean --direction?`` when ``message`` says a required option is missing and
    ``given`` holds an option ``parser`` does not know that is close to one it does
    (``--drection``); argparse reports the missing option before the unknown one."""
    if "required" not in message or "did you mean" in message:
        return ""
    known = option_strings(parser)
    for arg in (g.split("=", 1)[0] for g in given if g.startswith("--")):
        close = None if arg in known else closest(arg, known)
        if close:
            return f"; did you mean {close} instead of {arg}?"
    return ""


def with_choice_hint(message: str) -> str:
    """argparse's ``invalid choice: 'X' (choose from ...)`` with the list replaced by the
    closest choice when one is close; other messages unchanged."""
    found = _CHOICE.search(message)
    if found is None:
        return message
    close = closest(found["value"], re.findall(r"'([^']*)'", found["choices"]))
    if close is None:
        return message
    return (f"{message[:found.start()]}invalid choice: '{found['value']}'; "
            f"did you mean '{close}'?")
