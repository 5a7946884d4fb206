"""Errors that end a command with a one-line message instead of a traceback."""

import string


class InputError(Exception):
    """A user's file, key or argument is wrong: exit code 2, one line naming what and where."""


class DeviceError(Exception):
    """A device stays unreachable or answers garbage after retries: exit code 1."""


class OutputError(Exception):
    """A result could not be written (disk full, file too large): exit code 1, one line saying what
    was kept and how to go on. What was written before it stays whole."""


class ParameterError(InputError):
    """A bad value of a named parameter of a job: exit code 2 like any bad input.

    ``template`` writes each parameter it names as a field (``"{select} {value}: must lie ..."``);
    ``values`` fills the other fields. ``str()`` shows the parameters by their names in the job,
    ``named(names)`` as the caller calls them (a command: its flags, ``{"select": "--select"}``).
    """

    def __init__(self, template: str, **values):
        self.template, self.values = template, values
        super().__init__(self.named({}))

    def named(self, names: dict[str, str]) -> str:
        fields = {field for _, field, _, _ in string.Formatter().parse(self.template) if field}
        parameters = {p: names.get(p, p) for p in fields - self.values.keys()}
        return self.template.format(**parameters, **self.values)
