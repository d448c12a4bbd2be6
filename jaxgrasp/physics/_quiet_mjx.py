"""Import ``mujoco.mjx`` once with its import-time notices kept off the user's stdout.

mujoco-mjx prints "Failed to import warp: ..." (twice) from ``mujoco.mjx.warp`` whenever the
optional ``warp`` extra is absent, at the first ``from mujoco import mjx`` of a process. Here
Warp is optional: ``backend="mjx-warp"`` without it raises an error that says what to install
(:func:`jaxgrasp.physics.warp_backend.make_warp_trial`), so the notice is noise on every run.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401  (imported for its side effect: the module cache)
