"""What every ``python -m jaxgrasp.*`` command does with bad input: one line, exit code 2."""

import sys

__all__ = ["USER_ERRORS", "fail", "interrupted", "stopped"]

#: Errors that mean "fix your input", printed without a traceback.
USER_ERRORS = (ValueError, FileNotFoundError, KeyError)


def fail(err: Exception) -> int:
    """Print ``error: ...`` on stderr; the command's exit code."""
    print(f"error: {err}", file=sys.stderr)
    return 2


def interrupted(err: BaseException) -> bool:
    """Ctrl-C, also when it reached the program through a JAX host callback (XLA re-raises
    the callback's KeyboardInterrupt as a runtime error that names it)."""
    return isinstance(err, KeyboardInterrupt) or "KeyboardInterrupt" in str(err)


def stopped(resume_hint: str) -> int:
    """Print one line on stderr after Ctrl-C (what is kept, how to go on); exit code 130."""
    print(f"interrupted: {resume_hint}", file=sys.stderr)
    return 130
