"""The one error type for user mistakes."""


class LtmError(Exception):
    """A user-facing error: bad input, a missing file, a refused overwrite.

    The message is one line that names the bad value and what was expected. The CLI prints it
    as ``ltm: error: <message>`` and exits with status 2; it never shows a traceback.
    """


class LtmWarning(UserWarning):
    """Something the user should know, done anyway (a skipped light, a path found by name).

    The message is one line; the CLI prints it as ``ltm: warning: <message>``.
    """
