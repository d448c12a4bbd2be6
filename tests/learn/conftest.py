"""Shared fixtures of the learning tests: ONE compiled trial per scene, identical shapes.

The real MJX trial of the test box compiles once per session (15-70 s on a CPU); every test
that simulates uses ``box_sim`` with ``CHAINS`` chains, so the compiled batch is reused. The
analytic ``fake_sim`` (instant) exercises orchestration, chain files and resume.
"""


import jax
import jax.numpy as jnp
import pytest

import jaxgrasp as jg
from jaxgrasp.physics.protocol import TrialResult

CHAINS = 4
#: Tiny runs: 10 burn-in + 40 iterations, 3 demos, a 120-point sketch.
SMALL = dict(iterations=40, burn_in=10, sketch_size=120, subsample_size=40, num_demos=3,
             demo_candidates=4)


@pytest.fixture(scope="session")
def small_params():
    return jg.learn.LearnParams(**SMALL)


@pytest.fixture(scope="session")
def box():
    return jg.objects.make_box()


@pytest.fixture(scope="session")
def box_sim(box):
    """The box's real trial (backend "auto": MuJoCo C on a CPU), for batches of CHAINS: the
    process's shared simulator, which runs given no trial use too."""
    return jg.learn.sim.shared_simulator(box, batch_size=CHAINS)


def make_fake_trial(half_extents=(0.03, 0.03, 0.05), num_contacts=4):
    """An analytic trial on an axis-aligned box standing on z = 0.

    Success: grasp center inside the box's outer half, closing axis (grasp-frame y) within
    ~14 degrees of x or y. Collision: center in the inner half or below the table. Slipped:
    other centers inside the box. Miss: centers outside.
    """
    h = jnp.asarray(half_extents, jnp.float32)
    center = jnp.array([0.0, 0.0, half_extents[2]], jnp.float32)

    @jax.jit
    def trial(grasps):
        grasps = jnp.asarray(grasps, jnp.float32)
        pos, q = grasps[:, :3], grasps[:, 3:]
        q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
        close = jax.vmap(jg.so3.to_matrix)(q)[:, :, 1]
        rel = (pos - center) / h
        inside = jnp.all(jnp.abs(rel) < 1.0, axis=-1)
        deep = jnp.all(jnp.abs(rel) < 0.5, axis=-1)
        align = jnp.maximum(jnp.abs(close[:, 0]), jnp.abs(close[:, 1]))
        good = inside & (align > 0.97)
        outcome = jnp.where(deep | (pos[:, 2] < 0.0), 2,
                            jnp.where(good, 0, jnp.where(inside, 1, 3))).astype(jnp.int32)
        eps = jnp.where(outcome <= 1, 0.05 + 0.1 * align, 0.0).astype(jnp.float32)
        return fake_result(outcome, eps, num_contacts)

    return trial


def fake_result(outcome, epsilon, num_contacts=4):
    """A TrialResult with ``outcome`` and ``epsilon`` (B,) and no contacts (traceable)."""
    b, k = outcome.shape[0], num_contacts
    return TrialResult(
        outcome=outcome, epsilon=epsilon, displacement=jnp.zeros(b, jnp.float32),
        contact_points=jnp.zeros((b, k, 3), jnp.float32),
        contact_normals=jnp.zeros((b, k, 3), jnp.float32),
        contact_mask=jnp.zeros((b, k), bool), pad_contact=jnp.zeros((b, 2), bool),
        unstable=jnp.zeros(b, bool), invalid=jnp.zeros(b, bool))


@pytest.fixture(scope="session")
def fake_trial():
    return make_fake_trial()


@pytest.fixture(scope="session")
def fake_sim(box, fake_trial):
    return jg.learn.Simulator(box, trial=fake_trial, batch_size=CHAINS)


@pytest.fixture(scope="session")
def kd_result(box, box_sim, small_params):
    """Kameleon + GDMC with the biased sketch on the box (real physics), shared by tests."""
    return jg.learn.active(box, method="kameleon_darting", sketch="biased", chains=CHAINS,
                           seed=0, params=small_params, trial=box_sim, progress=False)


@pytest.fixture(scope="session")
def rw_result(box, box_sim, small_params):
    """The random-walk baseline on the same budget (real physics)."""
    return jg.learn.active(box, method="random_walk", chains=CHAINS, seed=0,
                           params=small_params, trial=box_sim, progress=False)
