"""Errors that a user can act on.

Anything raised as :class:`UserInputError` reaches the command line as one paragraph
without a traceback; everything else is a bug in taichi_mex and keeps its traceback.
"""


class UserInputError(ValueError):
    """Bad input from the user: a file, an option or a combination of options."""


class GCodeError(UserInputError):
    """A G-code file that taichi_mex cannot turn into a trustworthy trajectory."""


class SimulationDiverged(RuntimeError):
    """The particle state became non-finite or exploded; the message names time and cause."""
