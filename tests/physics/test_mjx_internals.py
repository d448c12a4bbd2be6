"""What jaxgrasp relies on in MJX's internals (physics/_mjx_internals.py), pinned.

The stacked collision against ``mjx.collision`` and the per-trial slots are checked in
``test_collision.py``; here: the re-implemented step is ``mjx.step``, the contact record reads
and writes, and the version check names the supported versions.
"""

from importlib.metadata import version

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

import jaxgrasp as jg
from jaxgrasp.physics import _mjx_internals as mi
from jaxgrasp.physics import load_scene, rules

GOOD = [0.0, 0.0, 0.085, 0.0, 1.0, 0.0, 0.0]  # top-down on the 6 x 6 x 10 cm box


@pytest.fixture(scope="module")
def box_state():
    """The box held top-down, pads 0.2 mm into its faces, fingers driven closed."""
    scene = load_scene(jg.objects.make_box((0.03, 0.03, 0.05), mass=0.2))
    m = mjx.put_model(scene.mj_model)
    q = scene.qpos0()
    pos, quat, _ = rules.object_pose_from_grasp(np.asarray(GOOD), np)
    oq = scene.ids.object_qpos
    q[oq : oq + 3], q[oq + 3 : oq + 7] = pos, quat
    q[list(scene.ids.finger_qpos)] = 0.0298
    d = mjx.make_data(m).replace(qpos=jnp.asarray(q, jnp.float32),
                                 ctrl=jnp.full(m.nu, -0.035, jnp.float32))
    return scene, m, d


@pytest.mark.slow  # the MJX step; its collision is checked against MJX in `make test`
def test_step_with_collision_is_mjx_step(box_state):
    """With MJX's own collision the re-implemented step is ``mjx.step``, bit for bit."""
    scene, m, d = box_state
    ours = jax.jit(lambda d: mi.step_with_collision(m, d, mjx.collision))(d)
    ref = jax.jit(lambda d: mjx.step(m, d))(d)
    assert (np.asarray(mi.contacts(ref).dist) < 0).sum() >= 2  # pads pressed: not vacuous
    for field in ("qpos", "qvel", "qacc", "qfrc_constraint", "qacc_warmstart"):
        np.testing.assert_array_equal(getattr(ours, field), getattr(ref, field), err_msg=field)
    np.testing.assert_array_equal(mi.contacts(ours).dist, mi.contacts(ref).dist)


def test_contact_record_reads_and_writes(box_state):
    scene, m, d = box_state
    # jitted: MJX's collision op by op takes ~30 s on a CPU
    con = jax.jit(lambda d: mi.contacts(mjx.collision(m, mjx.kinematics(m, d))))(d)
    n = 4 * len(scene.ids.layout.pair_box)  # 4 box-mesh contacts per (gripper box, piece)
    assert con.dist.shape == (n,) and con.geom.shape == (n, 2) and con.frame.shape == (n, 3, 3)
    d2 = mi.with_contacts(d, con.replace(dist=con.dist + 1.0))
    np.testing.assert_array_equal(mi.contacts(d2).dist, con.dist + 1.0)


def test_version_check_names_the_supported_versions():
    mi.check_version(version("mujoco-mjx"))  # the installed one (else the import failed)
    for ok in ("3.3.3", "3.17.0", "3.99.1"):
        mi.check_version(ok)
    for bad in ("3.3.2", "3.2.7", "4.0.0"):
        with pytest.raises(ImportError, match=r"mujoco-mjx >= 3\.3\.3, < 4"):
            mi.check_version(bad)
