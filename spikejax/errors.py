"""Errors that the CLI reports in one line, without a traceback."""


class UserError(Exception):
    """A mistake in what the user asked for (a bad file, a bad flag, a bad value)."""
