"""The grasp trial on MuJoCo's C engine (``mujoco.rollout``), reached from JAX by a callback.

``make_mujoco_trial(scene)`` (or ``make_trial(scene, backend="mujoco")``) returns
``trial(grasps (B, 7)) -> TrialResult`` with the same protocol, thresholds and result fields
as the MJX trial (:mod:`jaxgrasp.physics.protocol`); it works under ``jit`` and ``vmap``
(``jax.pure_callback`` with ``vmap_method="broadcast_all"``: an outer vmap, e.g. over MCMC
chains, becomes one host call with all chains' grasps).

Split between host and JAX:

- host (numpy + MuJoCo C, float64): placement and collision pass (``mj_kinematics`` +
  ``mj_collision`` per trial), then ONE ``mujoco.rollout`` call over the non-colliding trials
  only (persistent thread pool, one ``MjData`` per thread, ``nthread = os.cpu_count()``), then
  displacement, instability and the pad-touch checks (miss, still held) from the returned
  states, each decided by the :mod:`jaxgrasp.physics.rules` function the MJX trial calls;
- JAX: the contacts after closing, the outcome and epsilon (only for trials that made contact)
  by :func:`jaxgrasp.physics.rules.trial_result` and ``protocol.with_epsilon``, as in the MJX
  trial: the two backends can differ only in the physics, never in the decisions, the
  bookkeeping or the contact geometry.

Open-loop schedule. ``mujoco.rollout`` takes per-step inputs, but the protocol's hold load is
the weight along the object's *current* -z axis (it turns with the object), which depends on
the state. Rather than stepping in Python, the C model gets one extra actuator: a ``general``
actuator with a *site* transmission on a site at the object's COM, gear
``(0, 0, 1, 0, 0, 0)``. Its force acts along the site's (= object's) local z axis at the COM,
so ``ctrl = -weight * w_t`` is exactly ``weight * w_t * (R_now @ -z)`` evaluated on the
pre-step state, as MJX does. The perturbation loads (gripper frame) are
open-loop ``xfrc_applied`` inputs (``control_spec`` with ``mjSTATE_XFRC_APPLIED``), added
only when the protocol has perturbations. The whole trial is one rollout call.

Other C-model settings: auto-reset disabled (a blow-up must show up as non-finite/fast
states and be reported ``unstable``, not silently reset), warm start zeroed per trial (MJX
starts every trial from zeros; the rollout threads reuse ``MjData``), and for the pad-touch
checks a twin model whose pad margins equal ``contact_tol`` (MJX reports the distance of every
candidate contact, C only generates contacts within the margin; margins do not change the
reported distance).

Contacts follow MJX's step semantics: ``mjx.step`` (like ``mj_step``) computes contacts on
the *pre-step* positions, so the "after closing" contacts are those of the state after
``close_steps - 1`` steps, expressed in the object frame of the state after ``close_steps``
steps (both states are returned to JAX), the "still held" contacts are those of the state
after ``num_steps - 1`` steps, and a pad touches (miss check) if it has a contact within
``contact_tol`` at any settle-phase step ``t`` in ``[close_ramp_steps, close_steps)`` (the
state after ``t`` steps).
"""

import os
import threading

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from jaxgrasp import so3
from jaxgrasp.physics import rules
from jaxgrasp.physics.contacts import contact_consts
from jaxgrasp.physics.inputs import MIN_BUCKET, bucket_size, check_grasps, pad_grasps, take_rows
from jaxgrasp.physics.protocol import G, epsilon_fn, schedule, with_epsilon

__all__ = ["MujocoEngine", "make_mujoco_trial"]

_WEIGHT_SITE = "jaxgrasp_weight"


def _c_models(scene):
    """(physics model with the weight actuator, contact-extraction twin with pad margins)."""
    spec = mujoco.MjSpec.from_string(scene.xml)
    spec.body("object").add_site(name=_WEIGHT_SITE, pos=np.asarray(scene.obj.com, float))
    spec.add_actuator(
        name=_WEIGHT_SITE,
        trntype=mujoco.mjtTrn.mjTRN_SITE,
        target=_WEIGHT_SITE,
        gear=[0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    )
    # A blow-up must stay visible (non-finite / fast states), not be reset to qpos0.
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    m = spec.compile()
    mc = spec.compile()
    for g in scene.ids.pad_geoms:
        mc.geom_margin[g] = scene.params.contact_tol
    return m, mc


class MujocoEngine:
    """Host-side trial runner on MuJoCo C (numpy in, a :func:`~jaxgrasp.physics.rules.raw_trial`
    dict of numpy arrays out; thread-safe).

    Parameters
    ----------
    scene : Scene
    nthread : int, optional
        Rollout threads (default ``os.cpu_count()``).
    """

    def __init__(self, scene, nthread=None):
        nthread = os.cpu_count() if nthread is None else int(nthread)
        if nthread < 1:
            raise ValueError(f"nthread must be >= 1, got {nthread}")
        self.scene, self.params, self.ids = scene, scene.params, scene.ids
        self.m, self.m_contact = _c_models(scene)
        self.nthread = nthread
        self._pool = None  # created on first use (no threads at construction/import time)
        self._datas = [mujoco.MjData(self.m) for _ in range(nthread)]
        self._d = mujoco.MjData(self.m)  # collision passes (calling thread)
        self._dc = mujoco.MjData(self.m_contact)
        self._lock = threading.Lock()
        self.num_calls = 0  # host calls (an outer vmap must not multiply them)

        p, m = self.params, self.m
        self.qpos0 = scene.qpos0()
        mujoco.mj_resetData(m, self._d)
        self._d.qpos[:] = self.qpos0
        self.state0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(m, self._d, self.state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self.nq, self.nv = m.nq, m.nv
        # FULLPHYSICS = (time, qpos, qvel, act, ...): qpos starts at 1.
        assert np.array_equal(self.state0[1 : 1 + m.nq], self.qpos0)

        sched = schedule(p, scene.gripper.open_width)
        weight_n = float(scene.obj.mass) * G
        T = p.num_steps
        ctrl = np.zeros((T, m.nu))
        ctrl[:, :2] = sched.ctrl
        ctrl[:, m.nu - 1] = -weight_n * sched.weight  # site actuator: along object +z
        self.control_spec = int(mujoco.mjtState.mjSTATE_CTRL)
        if np.any(sched.perturb != 0):
            xfrc = np.zeros((T, m.nbody, 6))
            xfrc[:, self.ids.object_body, :3] = weight_n * sched.perturb
            ctrl = np.concatenate([ctrl, xfrc.reshape(T, -1)], axis=1)
            self.control_spec |= int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
        self.control = ctrl[None]
        self.com = np.asarray(scene.obj.com, np.float64)
        self.corners = np.asarray(scene.corners, np.float64)
        self.support_z = float(scene.obj.support_z)

    # ----------------------------------------------------------------------------- helpers
    def _pad_distances(self, qpos):
        """(2,) each pad's closest contact at this state (:func:`rules.pad_distances`)."""
        m, d = self.m_contact, self._dc
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        n = d.ncon
        return rules.pad_distances(d.contact.dist[:n], d.contact.geom[:n], self.ids.pad_geoms, np)

    def _penetration(self, qpos):
        m, d = self.m, self._d
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        return -float(np.min(d.contact.dist[: d.ncon])) if d.ncon else -np.inf

    def place(self, grasps):
        """Placed qpos (N, nq) and collision flags (N,) of float grasps (N, 7)."""
        finite, g = rules.finite_grasps(np.asarray(grasps, np.float64), np)
        g = rules.normalize_grasps(g, np)
        pos, quat, _ = rules.object_pose_from_grasp(g, np)
        qpos = np.tile(self.qpos0, (g.shape[0], 1))
        oq = self.ids.object_qpos
        qpos[:, oq : oq + 3] = pos
        qpos[:, oq + 3 : oq + 7] = quat
        below = rules.below_support(g, self.corners, self.support_z, np)
        penetration = np.full(g.shape[0], -np.inf)
        for i in np.flatnonzero(finite & ~below):  # one cheap collision pass, no rollout
            penetration[i] = self._penetration(qpos[i])
        return qpos, rules.placement_collision(finite, below, penetration, self.params)

    def _pool_get(self):
        if self._pool is None:
            self._pool = mj_rollout.Rollout(nthread=self.nthread if self.nthread > 1 else 0)
        return self._pool

    def rollout(self, qpos):
        """States (N, T, nstate) of the protocol rollout from placed qpos (N, nq)."""
        n = qpos.shape[0]
        init = np.tile(self.state0, (n, 1))
        init[:, 1 : 1 + self.nq] = qpos
        state, _ = self._pool_get().rollout(
            self.m,
            self._datas,
            init,
            self.control,
            control_spec=self.control_spec,
            initial_warmstart=np.zeros((n, self.nv)),  # MJX starts every trial from zeros
        )
        return state

    # ------------------------------------------------------------------------------ driver
    def __call__(self, grasps):
        """Run a batch of grasps (..., 7) -> :func:`~jaxgrasp.physics.rules.raw_trial` dict
        with leading dims (...)."""
        grasps = np.asarray(grasps)
        lead = grasps.shape[:-1]
        with self._lock:
            self.num_calls += 1
            raw = self._run(grasps.reshape(-1, 7))
        return {k: v.reshape(lead + v.shape[1:]) for k, v in raw.items()}

    def _run(self, grasps):
        p, ids = self.params, self.ids
        N, T, cs = grasps.shape[0], p.num_steps, p.close_steps
        out = rules.raw_trial(
            collision=np.ones(N, bool),
            miss=np.zeros(N, bool),
            slipped=np.zeros(N, bool),
            bad=np.zeros(N, bool),
            max_disp=np.zeros(N, np.float32),
            pad_contact=np.zeros((N, 2), bool),
            pre_q=np.tile(self.qpos0.astype(np.float32), (N, 1)),
            snap_q=np.tile(self.qpos0.astype(np.float32), (N, 1)),
        )
        if N == 0:
            return out
        qpos, collision = self.place(grasps)
        out["collision"] = collision
        todo = np.flatnonzero(~collision)
        if todo.size == 0:
            return out
        state = self.rollout(qpos[todo])
        qs = state[:, :, 1 : 1 + self.nq]
        vs = state[:, :, 1 + self.nq : 1 + self.nq + self.nv]
        with np.errstate(invalid="ignore"):
            bad = ~np.all(rules.stable(qs, vs, p, np), axis=1)

        oq = ids.object_qpos
        pos = qs[:, :, oq : oq + 3]
        rot = so3.to_matrix(qs[:, :, oq + 3 : oq + 7], np)  # (n, T, 3, 3)
        # Max over the hold (steps cs .. T-1) relative to the pose after closing.
        disp = rules.displacement(pos[:, cs - 1, None], rot[:, cs - 1, None], pos[:, cs:],
                                  rot[:, cs:], self.com, np)
        max_disp = np.max(disp, axis=1)

        settle_start, settle_stop = rules.settle_window(p)
        fq = np.asarray(ids.finger_qpos)
        for j, i in enumerate(todo):
            out["bad"][i] = bad[j]
            if bad[j]:
                continue  # reported MISS/unstable; contacts are masked anyway

            def after(t, j=j, i=i):
                # The state after t steps, whose contacts mjx.step (like mj_step) uses at step t.
                return qs[j, t - 1] if t >= 1 else qpos[i]

            # Closest approach over the settle phase, from its last step back, only while a
            # pad is missing (as the MJX rollout's pad_min).
            dist = self._pad_distances(after(settle_stop - 1))
            for t in range(settle_stop - 2, settle_start - 1, -1):
                if rules.touching(dist, p).all():
                    break
                dist = np.minimum(dist, self._pad_distances(after(t)))
            touch = rules.touching(dist, p)
            held = rules.touching(self._pad_distances(after(T - 1)), p).all()
            out["miss"][i] = rules.missed(touch, qs[j, cs - 1, fq], p, np)
            out["slipped"][i] = rules.slipped(max_disp[j], held, p)
            out["max_disp"][i] = max_disp[j]
            out["pad_contact"][i] = touch
            out["pre_q"][i], out["snap_q"][i] = after(cs - 1), qs[j, cs - 1]
        return out


def _raw_shapes(B, nq):
    s = jax.ShapeDtypeStruct
    return rules.raw_trial(
        collision=s((B,), jnp.bool_),
        miss=s((B,), jnp.bool_),
        slipped=s((B,), jnp.bool_),
        bad=s((B,), jnp.bool_),
        max_disp=s((B,), jnp.float32),
        pad_contact=s((B, 2), jnp.bool_),
        pre_q=s((B, nq), jnp.float32),
        snap_q=s((B, nq), jnp.float32),
    )


def make_mujoco_trial(scene, *, nthread=None, min_bucket=MIN_BUCKET):
    """Build the grasp trial of a scene on MuJoCo C (see the module docstring).

    Parameters
    ----------
    scene : Scene
    nthread : int, optional
        Rollout threads (default ``os.cpu_count()``).
    min_bucket : int or None
        A call on concrete grasps (not traced) pads the batch with
        :data:`~jaxgrasp.physics.inputs.PAD_GRASP` rows to
        :func:`~jaxgrasp.physics.inputs.bucket_size` and slices the result back, so batch
        sizes 1...1024 compile the epsilon and bookkeeping at most 8 times (padded rows are
        collisions decided on the host: no rollout, no epsilon). Under an outer
        ``jit``/``vmap`` the caller's compilation owns the shape and nothing is padded.
        None: compile per batch size.

    Returns
    -------
    trial : callable ``grasps (B, 7) -> TrialResult``, jitted; works under ``jit``/``vmap``.
        ``trial.engine`` is the host :class:`MujocoEngine` (numpy in/out, no JAX);
        ``trial.jitted`` the jitted core ``(contact consts, grasps) -> TrialResult``.
    """
    engine = MujocoEngine(scene, nthread)
    cc = contact_consts(scene)

    @jax.jit
    def run(cc, grasps):
        # broadcast_all: an outer vmap (chains) becomes ONE host call with all grasps.
        raw = jax.pure_callback(
            engine, _raw_shapes(grasps.shape[0], engine.nq), grasps, vmap_method="broadcast_all"
        )
        # C states are float64 cast to float32: their quaternions are renormalized.
        # Contacts only for the trials whose contacts count (rules.trial_results).
        res = rules.trial_results(raw, cc, scene.params, scene.ids, renormalize=True)
        # Epsilon only for the trials that made contact (see protocol.with_epsilon).
        eps = epsilon_fn(jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
                         jnp.float32(scene.obj.max_radius))
        return with_epsilon(res, eps)

    def trial(grasps):
        grasps = check_grasps(grasps)
        n = grasps.shape[0]
        if min_bucket is None or isinstance(grasps, jax.core.Tracer) or n == 0:
            return run(cc, jnp.asarray(grasps, jnp.float32))
        size = bucket_size(n, min_bucket)
        res = run(cc, jnp.asarray(pad_grasps(grasps, size)))
        return take_rows(res, n)

    trial.engine = engine
    trial.jitted = run
    return trial
