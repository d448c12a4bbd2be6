"""What every ``python -m jaxgrasp.*`` command does with bad input: one line, exit code 2."""

import sys

__all__ = ["USER_ERRORS", "fail"]

#: Errors that mean "fix your input", printed without a traceback.
USER_ERRORS = (ValueError, FileNotFoundError, KeyError)


def fail(err: Exception) -> int:
    """Print ``error: ...`` on stderr; the command's exit code."""
    print(f"error: {err}", file=sys.stderr)
    return 2
