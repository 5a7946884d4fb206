"""A job's messages in a command's words: the job names its parameters, the command its flags."""

from __future__ import annotations

from collections.abc import Iterator
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
