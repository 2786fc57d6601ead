"""Errors that are the user's to fix, reported as one line without a traceback."""


class UserError(Exception):
    """A mistake of the user's (bad file, bad value, busy port): one line, exit status 2."""
