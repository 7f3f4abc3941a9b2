"""An error as one line of text: what every row, table and message of the project shows of a failure."""

from __future__ import annotations

import math

__all__ = ["one_line"]

#: Longest text :func:`one_line` returns (longer ones end in "...").
ONE_LINE_LIMIT = 400


def one_line(error: BaseException | str | None, stage: str | None = None, *, with_type: bool = True,
             limit: int = ONE_LINE_LIMIT) -> str:
    """An exception, or a recorded error text, on one line of at most ``limit`` characters.

    An exception reads ``Type: message`` (``with_type=False``: the message alone; the type's name
    when the message is empty), its message's first non-empty line with whitespace runs collapsed;
    a recorded text (a ``str``) has its whitespace runs collapsed; None or NaN (no text recorded)
    reads ``(no error text recorded)``. ``stage`` is put in front as ``stage: ...``.
    """
    if error is None or (isinstance(error, float) and math.isnan(error)):
        text = "(no error text recorded)"
    elif isinstance(error, BaseException):
        lines = [line for line in str(error).splitlines() if line.strip()]
        message = " ".join(lines[0].split()) if lines else ""
        name = type(error).__name__
        text = (f"{name}: {message}" if with_type else message) if message else name
    else:
        text = " ".join(str(error).split())
    if stage:
        text = f"{stage}: {text}"
    return text if len(text) <= limit else text[:limit - 3] + "..."
