"""The suite's own checks can fail: the deadlock check flags threads that stop for good."""

import pytest


def test_the_deadlock_check_flags_blocked_threads(on_two_pool_threads):
    # The call returns once (on the main thread), then blocks both pool threads forever on an
    # event nobody sets: no call finishes and no CPU is spent, as in a real deadlock.
    setup = "import threading\nnever = threading.Event()\ncalls = []\n"
    with pytest.raises(AssertionError, match="alive 2"):
        on_two_pool_threads(setup, "calls.append(1); len(calls) > 1 and never.wait()",
                            repeats=1, stall_s=3)


def test_the_deadlock_check_passes_threads_that_finish(on_two_pool_threads):
    on_two_pool_threads("import math\n", "math.fsum(range(10_000))", repeats=50, stall_s=3)
