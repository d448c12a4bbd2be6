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
  displacement, instability and the pad-touch checks (miss, still held) from the returned states;
- JAX: the contacts after closing (:func:`jaxgrasp.physics.contacts.grasp_contacts` on the
  returned state), the outcome decision (``protocol.decide_outcome``) and epsilon
  (``jaxgrasp.quality.epsilon``, only for trials that made contact: ``protocol.with_epsilon``):
  literally the functions the MJX trial uses, so the two backends can differ only in the
  physics, never in the bookkeeping or the contact geometry.

Open-loop schedule. ``mujoco.rollout`` takes per-step inputs, but the protocol's hold load is
the weight along the object's *current* -z axis (it turns with the object, see
``trial._rollout``), which depends on the state. Rather than stepping in Python, the C model
gets one extra actuator: a ``general`` actuator with a *site* transmission on a site at the
object's COM, gear ``(0, 0, 1, 0, 0, 0)``. Its force acts along the site's (= object's) local
z axis at the COM, so ``ctrl = -weight * w_t`` is exactly ``weight * w_t * (R_now @ -z)``
evaluated on the pre-step state, as MJX does. The perturbation loads (gripper frame) are
open-loop ``xfrc_applied`` inputs (``control_spec`` with ``mjSTATE_XFRC_APPLIED``), added
only when the protocol has perturbations. The whole trial is one rollout call.

Other C-model settings: auto-reset disabled (a blow-up must show up as non-finite/fast
states and be reported ``unstable``, not silently reset), warm start zeroed per trial (MJX
starts every trial from zeros; the rollout threads reuse ``MjData``), and for the
pad-touch checks a twin model whose pad margins equal ``contact_tol`` (MJX reports the distance of
every candidate contact, C only generates contacts within the margin; margins do not change
the reported distance).

Contacts follow MJX's step semantics: ``mjx.step`` (like ``mj_step``) computes contacts on
the *pre-step* positions, so the "after closing" contacts are those of the state after
``close_steps - 1`` steps, expressed in the object frame of the state after ``close_steps``
steps (both states are returned to JAX), the "still held" contacts are those of the state
after ``num_steps - 1`` steps, and a
pad touches (miss check) if it has a contact within ``contact_tol`` at any settle-phase step
``t`` in ``[close_ramp_steps, close_steps)`` (the state after ``t`` steps).
"""

import os
import threading

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from jaxgrasp.physics.contacts import contact_consts, grasp_contacts
from jaxgrasp.physics.inputs import check_grasps
from jaxgrasp.physics.protocol import (
    G,
    assemble_result,
    epsilon_fn,
    quat_to_mat,
    schedule,
    with_epsilon,
)

__all__ = ["MujocoEngine", "make_mujoco_trial", "RawTrial"]

_WEIGHT_SITE = "jaxgrasp_weight"
_DEFAULT_GRASP = np.array([0, 0, 1.0, 1, 0, 0, 0])


def _quat_to_mat(q):
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotations (numpy float64)."""
    w, x, y, z = (q[..., i] for i in range(4))
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


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


def RawTrial(**fields):
    """Host results of a batch (a plain dict, i.e. a pytree): collision, miss, slipped, bad,
    max_disp, pad_contact, pre_q (the state whose contacts count after closing), snap_q (the
    state after closing); contacts, the outcome and epsilon are decided in JAX."""
    return dict(fields)


class MujocoEngine:
    """Host-side trial runner on MuJoCo C (numpy in, :class:`RawTrial` out; thread-safe).

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
    def _pad_touch(self, qpos):
        """(2,) whether each pad has a contact with distance < contact_tol at this state."""
        m, d = self.m_contact, self._dc
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        n = d.ncon
        geom, dist = np.array(d.contact.geom[:n]), np.array(d.contact.dist[:n])
        on = dist < self.params.contact_tol
        return np.array([np.any(on & np.any(geom == pad, axis=1)) for pad in self.ids.pad_geoms])

    def _penetration(self, qpos):
        m, d = self.m, self._d
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        return -float(np.min(d.contact.dist[: d.ncon])) if d.ncon else -np.inf

    def place(self, grasps):
        """Placed qpos (N, nq) and collision flags (N,) of float grasps (N, 7)."""
        g = np.asarray(grasps, np.float64)
        finite = np.all(np.isfinite(g), axis=1)
        g = np.where(finite[:, None], g, _DEFAULT_GRASP)
        t, q = g[:, :3], g[:, 3:]
        n = np.linalg.norm(q, axis=1, keepdims=True)
        ok = n > 1e-9
        q = np.where(ok, q / np.where(ok, n, 1.0), np.array([1.0, 0, 0, 0]))
        q_inv = q * np.array([1.0, -1.0, -1.0, -1.0])
        rot = _quat_to_mat(q_inv)
        qpos = np.tile(self.qpos0, (g.shape[0], 1))
        oq = self.ids.object_qpos
        qpos[:, oq : oq + 3] = -np.einsum("nij,nj->ni", rot, t)
        qpos[:, oq + 3 : oq + 7] = q_inv
        # Support plane: z of the gripper corners in the object frame.
        z = self.corners @ _quat_to_mat(q)[:, 2].T + t[:, 2]
        collision = ~finite | np.any(z < self.support_z, axis=0)
        for i in np.flatnonzero(~collision):  # one cheap collision pass, no rollout
            collision[i] = self._penetration(qpos[i]) > self.params.collision_tol
        return qpos, collision

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
        """Run a batch of grasps (..., 7) -> :class:`RawTrial` with leading dims (...)."""
        grasps = np.asarray(grasps)
        lead = grasps.shape[:-1]
        with self._lock:
            self.num_calls += 1
            raw = self._run(grasps.reshape(-1, 7))
        return {k: v.reshape(lead + v.shape[1:]) for k, v in raw.items()}

    def _run(self, grasps):
        p, ids = self.params, self.ids
        N, T, cs = grasps.shape[0], p.num_steps, p.close_steps
        out = RawTrial(
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
            ok = (
                np.all(np.isfinite(qs), axis=2)
                & np.all(np.isfinite(vs), axis=2)
                & (np.max(np.abs(vs), axis=2) < p.max_speed)
            )
        bad = ~np.all(ok, axis=1)

        oq = ids.object_qpos
        pos = qs[:, :, oq : oq + 3]
        quat = qs[:, :, oq + 3 : oq + 7]
        quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
        rot = _quat_to_mat(quat)  # (n, T, 3, 3)
        pos_s, rot_s = pos[:, cs - 1], rot[:, cs - 1]
        # Displacement rel. to the gripper of the COM and of the material point at the grasp
        # center after closing, max over the hold (steps cs .. T-1), as trial._rollout.
        com_s = rot_s @ self.com + pos_s
        com_t = rot[:, cs:] @ self.com + pos[:, cs:]
        pt_obj = np.einsum("nji,nj->ni", rot_s, -pos_s)  # R_s^T (-p_s)
        pt_t = np.einsum("ntij,nj->nti", rot[:, cs:], pt_obj) + pos[:, cs:]
        d_com = np.linalg.norm(com_t - com_s[:, None], axis=-1)
        d_pt = np.linalg.norm(pt_t, axis=-1)
        max_disp = np.max(np.maximum(d_com, d_pt), axis=1)

        pre_snap = qs[:, cs - 2] if cs >= 2 else qpos[todo]
        pre_end = qs[:, T - 2] if T >= 2 else qpos[todo]
        fq = np.asarray(ids.finger_qpos)
        for j, i in enumerate(todo):
            out["bad"][i] = bad[j]
            if bad[j]:
                continue  # reported MISS/unstable; contacts are masked anyway
            # Pad contact = closest approach over the settle phase (steps ramp .. cs-1, whose
            # contacts are those of the states after t steps), as trial._rollout's pad_min;
            # from the last one back, only while a pad is missing.
            touch = self._pad_touch(pre_snap[j])
            for t in range(cs - 2, p.close_ramp_steps - 1, -1):
                if touch.all():
                    break
                touch |= self._pad_touch(qs[j, t - 1] if t >= 1 else qpos[i])
            held = self._pad_touch(pre_end[j])
            closed = np.any(qs[j, cs - 1, fq] < p.closed_tol)
            out["miss"][i] = ~touch.all() | closed
            out["slipped"][i] = (max_disp[j] > p.slip_tol) | ~held.all()
            out["max_disp"][i] = max_disp[j]
            out["pad_contact"][i] = touch
            out["pre_q"][i], out["snap_q"][i] = pre_snap[j], qs[j, cs - 1]
        return out


def _raw_shapes(B, nq):
    s = jax.ShapeDtypeStruct
    return RawTrial(
        collision=s((B,), jnp.bool_),
        miss=s((B,), jnp.bool_),
        slipped=s((B,), jnp.bool_),
        bad=s((B,), jnp.bool_),
        max_disp=s((B,), jnp.float32),
        pad_contact=s((B, 2), jnp.bool_),
        pre_q=s((B, nq), jnp.float32),
        snap_q=s((B, nq), jnp.float32),
    )


def _finish(raw, cc, scene):
    """TrialResult of one trial from its host results, epsilon left 0 (same bookkeeping as
    trial._finish)."""
    p, ids, oq = scene.params, scene.ids, scene.ids.object_qpos
    pos_s = raw["snap_q"][oq : oq + 3]
    quat = raw["snap_q"][oq + 3 : oq + 7]
    rot_s = quat_to_mat(quat / jnp.linalg.norm(quat))
    pts, nrm, msk = grasp_contacts(cc, raw["pre_q"], pos_s, rot_s, p, ids)
    return assemble_result(
        raw["collision"], raw["miss"], raw["slipped"], raw["bad"], msk, pts, nrm,
        raw["max_disp"], raw["pad_contact"],
    )


def make_mujoco_trial(scene, *, nthread=None):
    """Build the grasp trial of a scene on MuJoCo C (see the module docstring).

    Parameters
    ----------
    scene : Scene
    nthread : int, optional
        Rollout threads (default ``os.cpu_count()``).

    Returns
    -------
    trial : callable ``grasps (B, 7) -> TrialResult``, jitted; works under ``jit``/``vmap``.
        ``trial.engine`` is the host :class:`MujocoEngine` (numpy in/out, no JAX).
    """
    engine = MujocoEngine(scene, nthread)
    cc = contact_consts(scene)

    @jax.jit
    def run(cc, grasps):
        # broadcast_all: an outer vmap (chains) becomes ONE host call with all grasps.
        raw = jax.pure_callback(
            engine, _raw_shapes(grasps.shape[0], engine.nq), grasps, vmap_method="broadcast_all"
        )
        res = jax.vmap(lambda r: _finish(r, cc, scene))(raw)
        # Epsilon only for the trials that made contact (see protocol.with_epsilon).
        eps = epsilon_fn(jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
                         jnp.float32(scene.obj.max_radius))
        return with_epsilon(res, eps)

    def trial(grasps):
        grasps = jnp.asarray(check_grasps(grasps), jnp.float32)
        if grasps.ndim != 2 or grasps.shape[-1] != 7:
            raise ValueError(f"grasps must have shape (B, 7), got {grasps.shape}")
        return run(cc, grasps)

    trial.engine = engine
    return trial
