"""A job's messages in a command's words: the job names its parameters, the command its flags."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from errors import InputError, ParameterError


@contextmanager
def parameters_as_flags(flags: dict[str, str]) -> Iterator[None]:
    """Re-raise a job's ``ParameterError`` as the one-line ``InputError`` a user reads, each
    parameter written as the flag that sets it (``{"select": "--select"}``)."""
    try:
        yield
    except ParameterError as exc:
        raise InputError(exc.named(flags)) from None


def number(parse: Callable[[str], float], what: str, valid: Callable[[float], bool], rule: str):
    """An argparse ``type``: ``parse(text)`` (a ``ValueError``: the text is not ``what``), kept if
    ``valid``, else refused with ``rule`` formatted with the value."""

    def convert(text: str):
        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not valid(value):
            raise argparse.ArgumentTypeError(rule.format(value))
        return value

    return convert


seed = number(int, "a whole number", lambda v: 0 <= v < 2**63, "{} must be from 0 to 2**63 - 1")
"""An argparse ``type`` for ``--seed``: numpy's generators take no negative seed."""
