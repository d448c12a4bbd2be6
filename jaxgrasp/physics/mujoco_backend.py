"""The grasp trial on MuJoCo's C engine (``mujoco.rollout``), reached from JAX by a callback.

``make_mujoco_trial(scene)`` (or ``make_trial(scene, backend="mujoco")``) returns
``trial(grasps (B, 7)) -> TrialResult`` with the same protocol, thresholds and result fields
as the MJX trial (:mod:`jaxgrasp.physics.protocol`); it works under ``jit`` and ``vmap``
(``jax.pure_callback`` with ``vmap_method="broadcast_all"``: an outer vmap, e.g. over MCMC
chains, becomes one host call with all chains' grasps).

Split between host and JAX:

- host (numpy + MuJoCo C, float64; :class:`MujocoEngine`): placement and collision pass
  (``mj_kinematics`` + ``mj_collision`` per trial), then ONE ``mujoco.rollout`` call per piece
  over its non-colliding trials only (persistent thread pool, one ``MjData`` per thread,
  ``nthread = os.cpu_count()``), then displacement, instability and the pad-touch checks
  (miss, still held) from the returned states, each decided by the
  :mod:`jaxgrasp.physics.rules` function the MJX trial calls;
- JAX, in a jitted stage called by the host: ``early``, on worker threads as soon as the
  rollout is done (the host runs the pad checks meanwhile), the contacts after closing
  (:func:`jaxgrasp.physics.rules.batch_contacts`) and epsilon of every trial with contacts
  on both pads (the others' is 0: all their wrenches push one way) and no finger at its
  closed limit (a miss, flagged by the engine after the rollout), a superset of the
  graspable ones, as two computations (the contacts' compiled without YNNPACK fusions,
  :func:`contact_options`), each shared by every object (:func:`shared_contacts`,
  :func:`object_epsilon`: the object is their argument); then ``late``, the outcome
  (:func:`jaxgrasp.physics.rules.assemble_results`, in numpy on the host: elementwise, cheaper
  than a dispatch), keeping epsilon of SUCCESS/SLIPPED only. The same functions as the MJX
  trial's (``trial_results`` then ``with_epsilon``): the two backends can differ only in the
  physics, never in the decisions, the bookkeeping or the contact geometry (beyond float
  round-off: compiled apart, the sums run in other orders).

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

import logging
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from functools import cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from jaxgrasp import so3
from jaxgrasp._exported import array_digest, locked_cache, stored_jit
from jaxgrasp.physics import rules
from jaxgrasp.physics.contacts import contact_consts, shared_consts, shared_ids
from jaxgrasp.physics.inputs import MIN_BUCKET, bucket_size, check_grasps, pad_grasps, take_rows
from jaxgrasp.physics.protocol import (
    G,
    Outcome,
    epsilon_fn,
    epsilon_where,
    result_shapes,
    schedule,
)
from jaxgrasp.physics.scene import load_scene

__all__ = ["MujocoEngine", "make_mujoco_trial"]

_WEIGHT_SITE = "jaxgrasp_weight"
_log = logging.getLogger(__name__)


def _log_warning(msg):
    # MuJoCo calls this from its rollout threads and aborts the process if it raises.
    try:
        _log.debug("MuJoCo: %s", msg)
    except BaseException:  # noqa: BLE001, S110
        pass


def route_mujoco_warnings() -> None:
    """Send MuJoCo's warnings to this module's logger (DEBUG) unless the process has set a
    handler: the trial reports an unstable rollout as ``unstable``, while MuJoCo's default
    prints each one and appends it to ``MUJOCO_LOG.TXT`` in the working directory."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)

#: XLA CPU compiles the C trial's contacts without YNNPACK fusions (the list of fusion types
#: holds only one the contacts never contain): its reductions on their small shapes cost
#: ~1.4x XLA's own loops (docs/design.md, "The JAX tail: contacts and epsilon").
_CONTACT_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_INDIVIDUAL_CONVOLUTION"}


@cache
def contact_options():
    """:data:`_CONTACT_OPTIONS` where this jaxlib accepts them, else None (XLA's defaults)."""
    try:
        jax.jit(jnp.negative).lower(np.zeros(1, np.float32)).compile(_CONTACT_OPTIONS)
    except Exception:  # an XLA that renamed or dropped the option: keep its defaults
        return None
    return dict(_CONTACT_OPTIONS)


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
        route_mujoco_warnings()
        self.m, self.m_contact = _c_models(scene)
        self.nthread = nthread
        self._pool = None  # created on first use (no threads at construction/import time)
        self._datas = [mujoco.MjData(self.m) for _ in range(nthread)]
        self._d = mujoco.MjData(self.m)  # collision passes (calling thread)
        self._dc = mujoco.MjData(self.m_contact)
        # Views made once: each attribute access builds a new numpy view (~1 us a state).
        self._d_qpos, self._dc_qpos = self._d.qpos, self._dc.qpos
        self._pads = tuple(int(g) for g in scene.ids.pad_geoms)
        self._lock = threading.Lock()
        self.num_calls = 0  # engine calls: one per pipeline piece, never one per chain

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
        """(N, 2) each pad's closest contact at each of the states qpos (N, nq)
        (:func:`rules.pad_distances` per state, in plain Python: a state has ~2 contacts, on
        which numpy's per-call overhead cost more than the collision pass itself)."""
        m, d, q_view = self.m_contact, self._dc, self._dc_qpos
        pad0, pad1 = self._pads
        kinematics, collision, inf = mujoco.mj_kinematics, mujoco.mj_collision, float("inf")
        out = []
        for q in qpos:
            q_view[:] = q
            kinematics(m, d)
            collision(m, d)
            a = b = inf
            if n := d.ncon:
                c = d.contact
                for dist, (g0, g1) in zip(c.dist[:n].tolist(), c.geom[:n].tolist(),
                                          strict=True):
                    if pad0 in (g0, g1):
                        a = min(a, dist)
                    if pad1 in (g0, g1):
                        b = min(b, dist)
            out.append((a, b))
        return np.array(out, np.float64).reshape(-1, 2)

    def _penetration(self, qpos):
        m, d = self.m, self._d
        self._d_qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        return -min(d.contact.dist[: d.ncon].tolist()) if d.ncon else -np.inf

    def place(self, grasps):
        """Placed qpos (N, nq) and collision flags (N,) of float grasps (N, 7)."""
        with self._lock:  # its collision passes share one MjData with start()
            return self._place(grasps)

    def _place(self, grasps):
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
        raw = self.finish(self.start(grasps.reshape(-1, 7)))
        return {k: v.reshape(lead + v.shape[1:]) for k, v in raw.items()}

    def start(self, grasps):
        """Placement, collision pass and rollout of grasps (N, 7): a dict whose ``raw`` holds
        ``collision``, ``bad``, ``pre_q`` and ``snap_q`` (what the contacts need, so JAX can
        start on them) and whose other entries :meth:`finish` completes with the pad checks."""
        with self._lock:
            self.num_calls += 1
            return self._start(np.asarray(grasps).reshape(-1, 7))

    def finish(self, rolled):
        """The pad checks of :meth:`start`'s output: the full raw trial dict."""
        with self._lock:
            return self._finish(rolled)

    def _start(self, grasps):
        p = self.params
        N, cs = grasps.shape[0], p.close_steps
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
        rolled = {"raw": out, "ok": np.zeros(0, np.int64), "done": np.zeros(0, np.int64),
                  "closed": np.zeros(N, bool)}
        if N == 0:
            return rolled
        qpos, collision = self._place(grasps)
        out["collision"] = collision
        todo = np.flatnonzero(~collision)
        if todo.size == 0:
            return rolled
        state = self.rollout(qpos[todo])
        qs = state[:, :, 1 : 1 + self.nq]
        vs = state[:, :, 1 + self.nq : 1 + self.nq + self.nv]
        if np.isfinite(state).all() and np.abs(vs).max() < p.max_speed:
            bad = np.zeros(todo.size, bool)  # every state sound: the rule's answer, ~10x faster
        else:
            with np.errstate(invalid="ignore"):
                bad = ~np.all(rules.stable(qs, vs, p, np), axis=1)
        out["bad"][todo] = bad
        ok = np.flatnonzero(~bad)  # unstable trials are reported MISS; contacts are masked
        done = todo[ok]
        rolled.update(qpos=qpos, qs=qs, ok=ok, done=done)
        every = np.arange(ok.size)
        out["pre_q"][done], out["snap_q"][done] = self._after(rolled, cs - 1, every), qs[ok, cs - 1]
        # A finger at its closed limit is a MISS already (float64, as finish decides it).
        fq = np.asarray(self.ids.finger_qpos)
        rolled["closed"][done] = rules.finger_closed(qs[ok, cs - 1][:, fq], p, np)
        return rolled

    @staticmethod
    def _after(rolled, t, rows):
        # The states after t steps, whose contacts mjx.step (like mj_step) uses at step t.
        qs, ok = rolled["qs"], rolled["ok"]
        return qs[ok[rows], t - 1] if t >= 1 else rolled["qpos"][rolled["done"][rows]]

    def _finish(self, rolled):
        out, ok, done = rolled["raw"], rolled["ok"], rolled["done"]
        if done.size == 0:
            return out
        p, ids = self.params, self.ids
        T, cs = p.num_steps, p.close_steps
        qs = rolled["qs"][ok]

        oq = ids.object_qpos
        pos = qs[:, :, oq : oq + 3]
        rot = so3.to_matrix(qs[:, :, oq + 3 : oq + 7], np)  # (n, T, 3, 3)
        # Max over the hold (steps cs .. T-1) relative to the pose after closing.
        disp = rules.displacement(pos[:, cs - 1, None], rot[:, cs - 1, None], pos[:, cs:],
                                  rot[:, cs:], self.com, np)
        max_disp = np.max(disp, axis=1)

        settle_start, settle_stop = rules.settle_window(p)
        fq = np.asarray(ids.finger_qpos)

        def after(t, rows):
            return self._after(rolled, t, rows)

        # Closest approach over the settle phase, from its last step back, only for the
        # trials with a pad still missing (as the MJX rollout's pad_min).
        every = np.arange(ok.size)
        dist = self._pad_distances(after(settle_stop - 1, every))
        for t in range(settle_stop - 2, settle_start - 1, -1):
            rows = np.flatnonzero(~rules.touching(dist, p).all(axis=1))
            if rows.size == 0:
                break
            dist[rows] = np.minimum(dist[rows], self._pad_distances(after(t, rows)))
        touch = rules.touching(dist, p)
        held = rules.touching(self._pad_distances(after(T - 1, every)), p).all(axis=1)
        out["miss"][done] = rules.missed(touch, qs[:, cs - 1][:, fq], p, np)
        out["slipped"][done] = rules.slipped(max_disp, held, p)
        out["max_disp"][done] = max_disp
        out["pad_contact"][done] = touch
        return out


#: A host call of ``n >= 2 * MIN_PIECE`` trials runs in this many engine pieces; each piece's
#: JAX tail (contacts, outcome, epsilon) is split over the worker threads and overlaps the
#: engine's next piece (see :func:`make_mujoco_trial`). Measured in ``docs/design.md``.
PIECES = 2
#: Smallest engine piece: below 2 x 256 trials one piece is faster, since the tail of the
#: first piece slows the rollout of the next as much as it overlaps it (full ÷ physics at
#: B = 128: 0.78-0.80 in one piece against 0.70-0.73 in two; docs/design.md, "The MuJoCo C
#: trial on the host").
MIN_PIECE = 256


def piece_sizes(n: int, workers: int) -> tuple[int, int]:
    """(trials per engine piece, trials per tail part) of a host call of ``n`` trials with
    ``workers`` tail threads; powers of two >= the smallest bucket when ``n`` is larger than
    it (the tail compiles once per bucket), the last piece padded."""
    n = int(n)
    if n <= MIN_BUCKET:
        return n, n
    piece = max(bucket_size(-(-n // PIECES), MIN_BUCKET), min(MIN_PIECE, bucket_size(n)))
    return piece, max(piece // max(int(workers), 1), MIN_BUCKET)


#: The raw trial fields the contacts (and the early epsilon) read: known after the rollout.
EARLY_KEYS = ("collision", "bad", "pre_q", "snap_q")


def early_inputs(raw, closed):
    """What the early stage reads: the :data:`EARLY_KEYS` of a raw trial, and ``closed``
    (B,), trials that need no epsilon: a finger at its closed limit (the engine's flags), or
    any other misses (every miss, where they are known)."""
    return {**{k: raw[k] for k in EARLY_KEYS}, "closed": closed}


class _Pipeline:
    """The C trial on the host, piece by piece: ``engine.start`` (placement, rollout: C
    threads), then ``early`` (JAX: contacts and epsilon from the states) in parts on worker
    threads (one per rollout thread) while this thread runs ``engine.finish`` (the pad
    checks, numpy + MuJoCo) and the next piece; ``late`` (numpy: outcome, masks) joins them.
    Called from an XLA thread (a sampler's host callback), one part per piece. Thread-safe;
    the workers start on first use."""

    def __init__(self, engine, early, late):
        self.engine, self.early, self.late = engine, early, late
        self.workers = max(1, engine.nthread)
        self._pool = None
        self._lock = threading.Lock()

    def _submit(self, fn, *args):
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="jaxgrasp-tail")
        return self._pool.submit(fn, *args)

    def _early(self, raw, dispatched=None):
        out = self.early(raw)  # both computations queued: XLA runs them without the GIL
        if dispatched is not None:
            dispatched.set()
        return jax.device_get(out)

    def _start_early(self, parts):
        """Submit ``early`` of each part on a worker and wait until all are dispatched: XLA
        then runs them without the GIL, which the caller's pad checks (numpy, MuJoCo) would
        otherwise hold for up to Python's switch interval (5 ms) before a worker could
        dispatch (the contacts, then epsilon)."""
        events = [threading.Event() for _ in parts]
        futures = [self._submit(self._signal_early, r, e)
                   for r, e in zip(parts, events, strict=True)]
        for ev in events:
            ev.wait()
        return futures

    def _signal_early(self, raw, dispatched):
        try:
            return self._early(raw, dispatched)
        finally:
            dispatched.set()  # also when early fails: the caller must not wait forever

    def __call__(self, grasps):
        g = np.asarray(grasps, np.float32)
        lead = g.shape[:-1]
        g = g.reshape(-1, 7)
        n = g.shape[0]
        piece, part = piece_sizes(n, self.workers)
        if isinstance(threading.current_thread(), threading._DummyThread):
            # Called by XLA (a sampler's host callback inside its running computation): there
            # the tail's parallel parts contend (docs/design.md, "The MuJoCo C trial on the
            # host"), so one per piece.
            part = piece
        if n == 0:
            raw = self.engine(g)
            return jax.device_get(self.late(raw, self._early(early_inputs(raw, raw["miss"]))))
        g = pad_grasps(g, -(-n // piece) * piece)
        cat = lambda *xs: np.concatenate(xs)  # noqa: E731
        raws, pending = [], []
        for lo in range(0, len(g), piece):
            rolled = self.engine.start(g[lo:lo + piece])
            # What the workers read; finish() below does not write it.
            early = early_inputs(rolled["raw"], rolled["closed"])
            # Rows whose contacts count dealt round-robin, those that need no epsilon among
            # them too: the parts get equal work.
            order = np.lexsort((early["closed"], early["collision"] | early["bad"]))
            order = np.concatenate([order[i::piece // part] for i in range(piece // part)])
            futures = self._start_early([{k: v[order[i:i + part]] for k, v in early.items()}
                                         for i in range(0, piece, part)])
            pending.append((order, futures))
            # The pad checks run here while the workers compute contacts and epsilon.
            raws.append(self.engine.finish(rolled))
        done = []
        for order, futures in pending:
            out = jax.tree.map(cat, *[f.result() for f in futures])
            done.append(jax.tree.map(lambda x, order=order: x[np.argsort(order)], out))
        res = jax.device_get(self.late(jax.tree.map(cat, *raws), jax.tree.map(cat, *done)))
        return jax.tree.map(lambda x: x[:n].reshape(lead + x.shape[1:]), res)


class _StandIn(NamedTuple):
    """The object of the scene whose kinematics the shared contact stage reads (a small
    tetrahedron): any object's scene has the same gripper bodies, joints and geoms first."""

    name: str = "stand_in"
    pieces: tuple = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 1e-2,)
    mass: float = 1.0
    com: tuple = (0.0, 0.0, 0.0)
    inertia: tuple = ((1e-4, 0, 0), (0, 1e-4, 0), (0, 0, 1e-4))


def _need(raw, msk):
    """The trials whose epsilon the early stage computes: contacts on both pads, and neither
    a collision, an unstable rollout nor a finger at its closed limit."""
    return ~(raw["collision"] | raw["bad"] | raw["closed"]) & rules.two_sided(msk)


def object_args(cc):
    """What :func:`shared_contacts`' stage takes of an object's consts: its arrays alone
    (flattening the stand-in's MJX model too cost ~1 ms per call)."""
    return cc.hulls, cc.offset, cc.pieces


@locked_cache
def shared_contacts(gripper, params):
    """The C trial's contact stage for every object of this gripper and these params: jitted
    ``(object_args(consts), raw) -> (points, normals, mask, need)`` of a batch, ``consts``
    the object's :func:`~jaxgrasp.physics.contacts.shared_consts` over the stand-in's
    (returned second, then the stand-in scene's ids).

    The object's hulls and piece poses are arguments of padded shapes, not constants: a
    new object reuses the program compiled for an earlier one of its padded sizes, in this
    process or (persistent compilation cache) an earlier one."""
    stand_in = load_scene(_StandIn(), gripper, params)
    base = contact_consts(stand_in)
    ngeom = stand_in.mj_model.ngeom

    def contacts(args, raw):
        hulls, offset, pieces = args
        ids = shared_ids(stand_in.ids, ngeom, pieces[0].shape[0])
        # C states are float64 cast to float32: their quaternions are renormalized.
        pts, nrm, msk = rules.batch_contacts(raw, base._replace(
            hulls=hulls, offset=offset, pieces=pieces), params, ids, renormalize=True)
        return pts, nrm, msk, _need(raw, msk)

    # The options (no YNNPACK) speed up the contacts and are kept off epsilon's loops
    # (docs/design.md, "The JAX tail: contacts and epsilon"). Stored: a fresh process reads
    # the traced program, keyed by what it closes over (the stand-in's consts by value).
    stage = stored_jit(contacts, name="contacts", compiler_options=contact_options(),
                       static=repr((gripper, params, stand_in.ids, ngeom, array_digest(base))))
    return stage, base, stand_in.ids


def object_epsilon(pts, nrm, msk, need, mu, com, radius, *, num_contacts, chunk):
    """The C trial's epsilon stage: :func:`~jaxgrasp.physics.protocol.epsilon_where` of the
    contacts with the object's friction ``mu``, ``com`` and ``radius`` as arguments (not
    constants), so one compiled program serves every object; stored (``_exported``)."""
    return _stored_epsilon(num_contacts, chunk)(pts, nrm, msk, need, mu, com, radius)


@locked_cache
def _stored_epsilon(num_contacts, chunk):
    def stage(pts, nrm, msk, need, mu, com, radius):
        return epsilon_where(pts, nrm, msk, need, epsilon_fn(mu, com, radius, num_contacts),
                             chunk)

    return stored_jit(stage, name="object_epsilon", static=repr((num_contacts, chunk)))


def make_mujoco_trial(scene, *, nthread=None, min_bucket=MIN_BUCKET, epsilon_chunk=None):
    """Build the grasp trial of a scene on MuJoCo C (see the module docstring).

    The JAX part (contacts, outcome, epsilon) is jitted on its own, called from the host: a
    large call's trials are simulated in :data:`PIECES` pieces (:func:`piece_sizes`), and
    each piece's contacts and epsilon run in parts on worker threads, overlapping the host's
    pad checks, the engine's next piece and each other (XLA runs one computation's loops on
    one thread). It has no host callback, so it is kept in the persistent compilation cache.

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
    epsilon_chunk : int or None
        None: the epsilon search's runs dealt to lanes (``jaxgrasp.quality.epsilon_batch``);
        an int: vmapped epsilon in chunks of that many trials (``protocol.map_where``, the
        method before the lanes, kept to compare). Same values up to float round-off.

    Returns
    -------
    trial : callable ``grasps (B, 7) -> TrialResult``, jitted; works under ``jit``/``vmap``.
        ``trial.engine`` is the host :class:`MujocoEngine` (numpy in/out, no JAX);
        ``trial.host`` the whole trial on the host, ``grasps (N, 7) -> TrialResult`` of numpy
        arrays (what the jitted trial's callback runs);
        ``trial.jitted`` the jitted core ``grasps -> TrialResult``;
        ``trial.tail`` the jitted JAX part ``(contact consts, raw trial) -> TrialResult``;
        ``trial.outcomes`` the outcome codes alone, ``grasps (N, 7) -> (N,) int32`` on the
        host, the trial's own (no contacts, no epsilon, nothing compiled).
    """
    engine = MujocoEngine(scene, nthread)
    stage, stand_in, stand_in_ids = shared_contacts(scene.gripper, scene.params)
    gripper_ids = lambda i: (i.object_body, i.object_qpos, i.pad_geoms)  # noqa: E731
    if gripper_ids(scene.ids) != gripper_ids(stand_in_ids):
        raise AssertionError("the stand-in scene's gripper ids differ from the scene's")
    shared = object_args(shared_consts(stand_in, scene))
    eps = epsilon_fn(jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
                     jnp.float32(scene.obj.max_radius), scene.params.num_contacts)
    params, ids = scene.params, scene.ids

    def contacts(cc, raw):
        # The reference: the scene's own kinematics and hulls (the pipeline's shared stage
        # gives the same contacts).
        pts, nrm, msk = rules.batch_contacts(raw, cc, params, ids, renormalize=True)
        return pts, nrm, msk, _need(raw, msk)

    def epsilon(pts, nrm, msk, need):
        return epsilon_where(pts, nrm, msk, need, eps, epsilon_chunk)

    # The object's friction, COM and radius are arguments of one module-level jit: every
    # object shares its compiled epsilon (the trial's largest JAX program but the contacts).
    shape = (jnp.float32(scene.friction), jnp.asarray(scene.obj.com, jnp.float32),
             jnp.float32(scene.obj.max_radius))

    def late(raw, early, xp=jnp):
        return rules.assemble_results(raw, early[:3], early[3], xp)

    @jax.jit
    def tail(cc, raw):
        # Every miss is known here (a finger at its closed limit is one of them).
        found = contacts(cc, early_inputs(raw, raw["miss"]))
        return late(raw, (*found[:3], epsilon(*found)))

    def shapes(B):
        # not jax.eval_shape(tail, ...): tracing the contacts took seconds for each new object
        return result_shapes(B, params.num_contacts)

    # Two computations shared by every object: the contacts (the object's hulls and piece
    # poses as arguments) and epsilon. Epsilon before the outcome is known (the host's pad
    # checks run meanwhile): for every trial with contacts on both pads and no finger at its
    # closed limit, the graspable ones with epsilon > 0 and a few misses (late() keeps the
    # graspable ones).
    def early(raw):
        found = stage(shared, raw)
        return (*found[:3], object_epsilon(*found, *shape, num_contacts=params.num_contacts,
                                           chunk=epsilon_chunk))

    host = _Pipeline(engine, early, partial(late, xp=np))

    @jax.jit
    def run(grasps):
        # broadcast_all: an outer vmap (chains) becomes ONE host call with all grasps. The
        # contact data are not an argument: flattening them cost ~1 ms per call.
        return jax.pure_callback(host, shapes(grasps.shape[0]), grasps,
                                 vmap_method="broadcast_all")

    def trial(grasps):
        grasps = check_grasps(grasps)
        n = grasps.shape[0]
        if min_bucket is None or isinstance(grasps, jax.core.Tracer) or n == 0:
            return rules.flag_invalid(run(jnp.asarray(grasps, jnp.float32)), grasps)
        size = bucket_size(n, min_bucket)
        res = run(jnp.asarray(pad_grasps(grasps, size)))
        return rules.flag_invalid(take_rows(res, n), grasps)

    def outcomes(grasps):
        # The outcome reads only the host's decisions (rules.decide_outcome), never the
        # contacts or epsilon: scoring robustness skips the JAX tail, most of a held grasp's cost.
        g = np.asarray(grasps, np.float32).reshape(-1, 7)
        raw = engine(g)
        out = rules.decide_outcome(raw["collision"], raw["miss"], raw["slipped"], raw["bad"], np)
        return np.where(rules.invalid_grasps(grasps), np.int32(Outcome.COLLISION), out)

    trial.engine = engine
    trial.host = host
    trial.jitted = run
    trial.tail = tail
    trial.outcomes = outcomes
    return trial
