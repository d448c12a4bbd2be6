"""Grasp-trial physics: parallel-jaw gripper, scene assembly and the batched grasp trial.

>>> scene = load_scene(jg.objects.make_box())
>>> trial = make_trial(scene)            # pure, jittable, vmappable
>>> res = trial(grasps)                  # grasps (B, 7): gripper pose in the object frame

See :mod:`jaxgrasp.physics.protocol` for the protocol, :mod:`jaxgrasp.physics.rules` for its
decisions (one code for both backends) and :mod:`jaxgrasp.physics.gripper` for the grasp-frame
convention.
"""

from jaxgrasp.physics import _quiet_mjx  # noqa: F401  (first: mjx imported quietly)
from jaxgrasp.physics.gripper import GRIPPERS, GripperParams, gripper
from jaxgrasp.physics.inputs import check_grasps, resolve_backend
from jaxgrasp.physics.protocol import Outcome, TrialParams, TrialResult
from jaxgrasp.physics.scene import Scene, load_scene
from jaxgrasp.physics.trial import make_trial

__all__ = [
    "GRIPPERS",
    "GripperParams",
    "Outcome",
    "Scene",
    "TrialParams",
    "TrialResult",
    "check_grasps",
    "gripper",
    "load_scene",
    "make_trial",
    "resolve_backend",
]
