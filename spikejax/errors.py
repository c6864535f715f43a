"""The one exception type for bad arguments, which the CLI reports in one line, without a traceback."""

__all__ = ["UserError"]


class UserError(ValueError):
    """A mistake in what the user asked for (a bad file, a bad flag, a bad value).

    A subclass of ``ValueError``, so ``except ValueError`` in library code catches
    it too; `spikejax.cli` prints its message and exits with status 2.
    """
