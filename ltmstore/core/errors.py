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


BRIEF_VALUES = 6  # values a message shows in full; a larger array is summarised


def brief(values) -> str:
    """``values`` for a one-line message: the list when it holds at most :data:`BRIEF_VALUES`
    numbers, else its shape, how many are not finite and its first values (a message never
    prints a whole array)."""
    import numpy as np

    try:
        a = np.asarray(values)
    except (TypeError, ValueError):  # ragged input: its repr, bounded
        text = repr(values)
        return text if len(text) <= 80 else f"{text[:77]}..."
    if a.size <= BRIEF_VALUES:
        return repr(a.tolist())
    try:
        bad = int(np.count_nonzero(~np.isfinite(a.astype(float))))
        finite = f", {bad} not finite" if bad else ""
    except (TypeError, ValueError):
        finite = ""
    head = ", ".join(map(str, a.ravel()[:3].tolist()))
    return f"array of shape {a.shape}{finite} ({head}, ...)"
