"""Errors that reach the user as one line.

Raise `CamnetError` with a message that names the file, field, device or
camera at fault and, where it helps, what to do. The CLI prints it alone and
exits non-zero; anything else is a bug and keeps its traceback.
"""


class CamnetError(Exception):
    """A problem with the user's input or environment, told in one line."""


class InputError(CamnetError):
    """Input data (a file, a message, a rig description) is malformed."""


class SolveError(CamnetError):
    """The calibration could not be computed from the data given."""
