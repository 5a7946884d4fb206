"""Errors that end a command with a one-line message instead of a traceback."""


class InputError(Exception):
    """A user's file, key or argument is wrong: exit code 2, one line naming what and where."""


class DeviceError(Exception):
    """A device stays unreachable or answers garbage after retries: exit code 1."""
