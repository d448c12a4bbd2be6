"""The grasp trial on MJX-Warp: MuJoCo Warp's physics through MJX (``impl="warp"``).

``make_warp_trial(scene)`` (or ``make_trial(scene, backend="mjx-warp")``) returns
``trial(grasps (B, 7)) -> TrialResult`` with the protocol, thresholds and result fields of the
other backends. Optional: needs ``warp-lang`` (``pip install 'jaxgrasp[warp]'``; mujoco-mjx
3.17 ships MuJoCo Warp itself under ``mujoco.mjx.third_party.mujoco_warp`` and pins
``warp-lang==1.18.0`` in its own ``warp`` extra); without it building the trial raises an
``ImportError`` that says so.

Why not the MJX trial's collision. The MJX rollout replaces MJX's collision by a per-trial
routine that writes each trial's nearest convex pieces into fixed contact slots of the
JAX-impl contact record (``_mjx_internals.step_with_collision``: ``mjx.step``'s stages, run
one by one with ``collide`` swapped in). On a Warp model ``mjx.step`` is one FFI call into
MuJoCo Warp (``mujoco.mjx.warp.forward.step``: forward and Euler inside Warp); the stages
after collision (constraints, solver) are not exposed for ``impl="warp"``, and Warp's contacts
live in its own buffer (``Data._impl.contact__*``, ``naconmax`` slots shared by every world
of a batch, with a world id), not in slots a JAX routine can fill. So there is no place to
put the slot collision. The honest closest thing, done here:

- **placement** (collision at placement, below the support plane): the MJX trial's own
  ``place`` (JAX, every piece), bit for bit the MJX decision;
- **rollout**: ``mjx.step`` on the Warp model of the full scene: Warp's own collision
  pipeline (broadphase, every piece against pads and palm, like MuJoCo C), the same model
  (timestep, solver, armature, stiff contacts), the same schedule and the same load (the
  weight along the object's current -z, ``xfrc_applied``), frozen at the last good state as
  in MJX;
- **decisions**: from the per-step states, as the MuJoCo C backend does: the pads' closest
  approach over the settle phase and at the end (the MJX collision routine evaluated on
  those states: JAX, 11 states per trial, not per step), displacement, miss, slip, the
  outcome and the contacts for epsilon by :mod:`jaxgrasp.physics.rules`.

The contact buffer: ``max_contacts`` per world (``naconmax = B * max_contacts``); a call that
fills it is reported (``RuntimeWarning``), since Warp then drops contacts.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from jaxgrasp._batching import fold_vmap
from jaxgrasp.physics import inputs, rules
from jaxgrasp.physics._mjx_internals import contacts
from jaxgrasp.physics.collision import collide_slots
from jaxgrasp.physics.inputs import MIN_BUCKET, bucket_size, check_grasps, pad_grasps, take_rows
from jaxgrasp.physics.mjx_scene import object_pose, place, scene_consts, slot_layout
from jaxgrasp.physics.protocol import epsilon_fn, with_epsilon

__all__ = ["make_warp_trial", "warp_available"]

#: Contacts allocated per world (trial) in Warp's shared buffer.
MAX_CONTACTS = 64


def warp_available() -> bool:
    """Whether MJX can run on MuJoCo Warp here (``warp-lang`` importable by MJX)."""
    return inputs._available("mjx-warp")


def _require_warp():
    if not warp_available():
        raise ImportError("backend 'mjx-warp' needs warp-lang (MJX's Warp implementation): "
                          "pip install 'jaxgrasp[warp]'")


def _pad_distances(c, slots, ids, q):
    """(2,) each pad's closest distance to the object at state ``q`` (the MJX collision)."""
    d = mjx.kinematics(c.m_roll, c.d0_roll.replace(qpos=q))
    d = collide_slots(c.m_roll, d, c.hulls, c.frames, slots, ids.object_body)
    con = contacts(d)
    return rules.pad_distances(con.dist, con.geom, ids.pad_geoms)


def _trial_core(c, mw, dw0, grasps, params, ids, slots):
    """Placement (JAX), Warp rollout, decisions; returns (TrialResult, peak contact count)."""
    qpos0, collision, _ = jax.vmap(lambda g: place(c, g, params, ids))(grasps)
    oq, ob = ids.object_qpos, ids.object_body

    def step(carry, x):
        d, bad, nacon = carry
        ctrl, w, pert = x

        def load(q):
            _, rot_now = object_pose(q, oq)
            return c.weight_n * (w * (rot_now @ jnp.array([0.0, 0.0, -1.0])) + pert)

        xfrc = d.xfrc_applied.at[:, ob, :3].set(jax.vmap(load)(d.qpos))
        d1 = jax.vmap(mjx.step, in_axes=(None, 0))(mw, d.replace(ctrl=jnp.broadcast_to(
            ctrl, d.ctrl.shape), xfrc_applied=xfrc))
        ok = jax.vmap(lambda q, v: rules.stable(q, v, params))(d1.qpos, d1.qvel)
        keep = lambda new, old: jnp.where(ok.reshape(-1, *[1] * (new.ndim - 1)), new, old)  # noqa: E731
        d1 = d1.replace(qpos=keep(d1.qpos, d.qpos), qvel=keep(d1.qvel, jnp.zeros_like(d.qvel)),
                        qacc_warmstart=keep(d1.qacc_warmstart, d.qacc_warmstart))
        nacon = jnp.maximum(nacon, jnp.max(d1._impl.nacon))
        return (d1, bad | ~ok, nacon), d1.qpos

    B = grasps.shape[0]
    d_init = jax.vmap(lambda q: dw0.replace(qpos=q))(qpos0)
    carry = (d_init, jnp.zeros(B, bool), jnp.int32(0))
    (_, bad, nacon), qs = jax.lax.scan(step, carry, (c.ctrl, c.weight, c.perturb))
    qs = jnp.swapaxes(qs, 0, 1)  # (B, T, nq): qs[:, t] is the state after t + 1 steps
    after = jnp.concatenate([qpos0[:, None], qs], axis=1)  # after[:, t]: after t steps
    cs, T = params.close_steps, params.num_steps
    start, stop = rules.settle_window(params)
    window = jnp.concatenate([after[:, start:stop], after[:, T - 1:T]], axis=1)
    dist = jax.vmap(jax.vmap(lambda q: _pad_distances(c, slots, ids, q)))(window)  # (B, W+1, 2)
    pad_contact = rules.touching(jnp.min(dist[:, :-1], axis=1), params)
    held = jnp.all(rules.touching(dist[:, -1], params), axis=-1)
    pose = jax.vmap(jax.vmap(lambda q: object_pose(q, oq)))
    pos_s, rot_s = pose(after[:, cs : cs + 1])
    pos_t, rot_t = pose(after[:, cs + 1 :])
    max_disp = jnp.max(rules.displacement(pos_s, rot_s, pos_t, rot_t, c.com), axis=1)
    snap_q = after[:, cs]
    raw = rules.raw_trial(
        collision=collision,
        miss=rules.missed(pad_contact, snap_q[:, np.asarray(ids.finger_qpos)], params),
        slipped=rules.slipped(max_disp, held, params),
        bad=bad,
        max_disp=max_disp,
        pad_contact=pad_contact,
        pre_q=after[:, cs - 1],
        snap_q=snap_q,
    )
    res = jax.vmap(lambda r: rules.trial_result(r, c.contacts, params, ids))(raw)
    eps = epsilon_fn(c.mu, c.com, c.radius, params.num_contacts)
    return with_epsilon(res, eps), nacon


def make_warp_trial(scene, *, min_bucket=MIN_BUCKET, max_contacts=MAX_CONTACTS):
    """Build the grasp trial of a scene on MJX-Warp (see the module docstring).

    Parameters
    ----------
    scene : Scene
    min_bucket : int or None
        Batch-shape buckets, as :func:`jaxgrasp.physics.make_trial`.
    max_contacts : int
        Contacts allocated per trial in Warp's shared contact buffer.

    Returns
    -------
    trial : callable ``grasps (B, 7) -> TrialResult``; works under ``jit`` and ``vmap``: an
        outer ``vmap`` (e.g. over MCMC chains) is folded into one call on all grasps
        (:func:`jaxgrasp._batching.fold_vmap`), since Warp's contact buffer is sized for
        the call's batch (a plain vmap would share one member's buffer among all members).
        ``trial.jitted`` is the jitted core.
    """
    _require_warp()
    rollout_model, slots = slot_layout(scene)
    c = scene_consts(scene, rollout_model)
    params, ids = scene.params, scene.ids
    with warnings.catch_warnings():
        # The object's pieces have friction 0 by design: a contact takes the larger friction
        # of its two geoms (MuJoCo's rule, and Warp's), the pad's. Warp warns per piece.
        warnings.filterwarnings("ignore", message=".*MJ_MINMU.*")
        mw = mjx.put_model(scene.mj_model, impl="warp")
    njmax = 4 * max_contacts + 4 * scene.mj_model.njnt + 8
    datas = {}

    def data(B):
        if B not in datas:
            # Concrete arrays even when first asked inside a trace (jit, vmap): cached.
            with jax.ensure_compile_time_eval():
                d = mjx.make_data(scene.mj_model, impl="warp", naconmax=B * max_contacts,
                                  njmax=njmax)
                datas[B] = d.replace(qpos=jnp.asarray(scene.qpos0(), jnp.float32))
        return datas[B]

    run = jax.jit(_trial_core, static_argnames=("params", "ids", "slots"))

    def trial(grasps):
        grasps = check_grasps(grasps)
        n = grasps.shape[0]
        traced = isinstance(grasps, jax.core.Tracer)
        size = n if (min_bucket is None or traced or n == 0) else bucket_size(n, min_bucket)
        g = jnp.asarray(grasps if size == n else pad_grasps(grasps, size), jnp.float32)
        res, nacon = run(c, mw, data(size), g, params, ids, slots)
        if not traced and int(nacon) >= size * max_contacts:
            warnings.warn(f"MJX-Warp filled its contact buffer ({size} x {max_contacts}); "
                          "contacts were dropped: raise max_contacts", RuntimeWarning,
                          stacklevel=2)
        return rules.flag_invalid(take_rows(res, n), grasps)

    trial = fold_vmap(trial, event_ndim=1)
    trial.jitted = run
    return trial
