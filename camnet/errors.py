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


def in_words(names, *, noun: str = "", last: str = "and") -> str:
    """Names as a message writes them: "a", "a and b", "a, b and c" (in the order given; "none" for none;
    `last` the word before the last name: "or" for a choice), after `noun` where one is given, plural
    ("cameras a and b") for more than one name."""
    names = [str(n) for n in names]
    listed = "none" if not names else names[0] if len(names) == 1 else f"{', '.join(names[:-1])} {last} {names[-1]}"
    if not noun:
        return listed
    return f"{noun}{'s' if len(names) > 1 else ''} {listed}"
