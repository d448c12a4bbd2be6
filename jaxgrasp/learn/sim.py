"""A compiled grasp trial shared by every phase of a learning run (demos, sketch, chains).

Compiling an MJX scene takes 15-70 s on a CPU. If the trial were traced into each sampler's
jitted scan, every new sampler (a new sketch, new modes, another method) would compile the
physics again. :class:`Simulator` compiles the trial once per scene and batch size, and the
samplers reach it through ``jax.pure_callback`` (:class:`GraspTarget`): under ``vmap`` over
chains the callback receives the whole (chains, 7) batch, so one MCMC step is still one
batched rollout, and the sampler's own compilation no longer contains the physics. With the
chains sharded over devices the trial is traced into the sampler instead, so every device runs
the rollouts of its own chains.

A sampler reaches its simulator through a :class:`HostTrial`, whose host function is one for
all and whose simulator id is an array (a jit argument): one compiled sampler serves every
simulator with the same result shapes, so a new object compiles no sampler. The runs that
build their own (no ``trial`` given: :func:`as_simulator`) share one process-wide
:class:`Simulator` per object content, gripper, protocol, backend and batch size
(:func:`shared_simulator`), and one trial per scene: a second run on the same object compiles
nothing.
"""

import hashlib
import itertools
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import density, mcmc, physics
from jaxgrasp.learn.inputs import resolve_object
from jaxgrasp.physics.inputs import (
    MIN_BUCKET,
    bucket_size,
    check_grasps,
    pad_grasps,
    resolve_backend,
)

__all__ = ["Simulator", "GraspTarget", "HostTrial", "as_simulator", "run_backend",
           "shared_simulator", "clear_shared"]

#: Shared simulators kept at most (least recently used dropped first): each holds MuJoCo data
#: per rollout thread, and its callback in the compiled samplers that use it.
MAX_SHARED = 8


class Simulator:
    """One object's grasp trial, jitted once and evaluated in fixed-size batches.

    Parameters
    ----------
    obj : GraspObject, Scene or str
        The object (or a scene already loaded with ``jg.physics.load_scene``).
    backend : str
        ``jg.physics.make_trial`` backend: ``"auto"`` (default: MuJoCo C when JAX runs on
        the CPU, MJX on an accelerator), ``"mjx"`` or ``"mujoco"``. ``self.backend`` holds
        the resolved name (with ``trial`` given it only labels that trial).
    trial : callable, optional
        A prebuilt trial ``(B, 7) -> TrialResult``, jittable or host-level (numpy in and
        out, e.g. ``make_trial(scene, compact=True)``); built from ``obj`` when None.
    batch_size : int, optional
        Every call pads its grasps to a multiple of this size (bucketed, see ``min_bucket``)
        so that one compiled trial serves all phases (use the number of chains). None: each
        call runs in one batch of its own (bucketed) size, split into chunks of
        ``max_bucket``.
    min_bucket : int or None
        Batch shapes are bucketed: a batch is padded with
        :data:`~jaxgrasp.physics.inputs.PAD_GRASP` rows (placement collisions: no rollout
        and no epsilon on MuJoCo C, a wasted rollout on MJX) to the power of two >=
        ``min_bucket`` (:func:`~jaxgrasp.physics.inputs.bucket_size`), so a session running
        1...1024 chains compiles the trial at most 8 times. None: exact sizes.
    max_bucket : int
        Largest batch of one trial call when ``batch_size`` is None.
    """

    def __init__(self, obj, *, backend="auto", trial=None, batch_size=None,
                 min_bucket=MIN_BUCKET, max_bucket=1024):
        backend = resolve_backend(backend)
        if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
            raise ValueError(f"batch_size must be a positive int or None, got {batch_size!r}")
        if min_bucket is not None:
            bucket_size(1, min_bucket)  # validates
        if not isinstance(max_bucket, int) or max_bucket < 1:
            raise ValueError(f"max_bucket must be a positive int, got {max_bucket!r}")
        self.scene = obj if hasattr(obj, "obj") else None
        # make_trial's trials and jax.jit functions trace (MuJoCo C reaches its engine by its
        # own callback); any other trial of a caller is traced once to find out (traceable).
        self._traceable = True if trial is None or isinstance(trial, jax.stages.Wrapped) else None
        if trial is None:
            if self.scene is None:
                self.scene = physics.load_scene(obj)
            trial = physics.make_trial(self.scene, backend=backend)
        self.obj = resolve_object(obj)
        self.backend = backend
        self.trial = trial
        self.batch_size = batch_size
        self.min_bucket, self.max_bucket = min_bucket, max_bucket
        self._jitted = jax.jit(trial)
        self._shapes = {}
        self._callback = None  # callback_trial(), made on first use
        with _ids_lock:
            self._token = next(_tokens)
            _simulators[self._token] = weakref.ref(
                self, lambda _, token=self._token: _simulators.pop(token, None))
        self.num_trials = 0  # grasps simulated (padding excluded): a rollout counter
        self._count_lock = threading.Lock()  # a cohort's threads may simulate together
        self.cohort = None  # a jaxgrasp.learn.Cohort merging this trial's calls with others'

    @property
    def traceable(self) -> bool:
        """Whether ``trial`` can be traced into a sampler: True for the trials this simulator
        builds (MJX, and MuJoCo C through its own callback) and for ``jax.jit`` functions;
        False for a host-level trial (numpy in and out), which fails to trace with abstract
        grasps."""
        if self._traceable is None:
            spec = jax.ShapeDtypeStruct((self.batch_size or 1, 7), jnp.float32)
            try:
                jax.eval_shape(self._jitted, spec)
                self._traceable = True
            except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
                self._traceable = False
        return self._traceable

    def result_shapes(self, batch: int):
        """ShapeDtypeStructs of ``trial`` on a (batch, 7) input (found once per size)."""
        if batch not in self._shapes:
            if self.traceable:
                # Tracing the jitted function fills the trace cache its first call reuses.
                spec = jax.ShapeDtypeStruct((batch, 7), jnp.float32)
                self._shapes[batch] = jax.eval_shape(self._jitted, spec)
            else:
                dummy = np.zeros((batch, 7), np.float32)
                dummy[:, 3] = 1.0
                with jax.ensure_compile_time_eval():  # may be asked while a sampler traces
                    out = self.trial(dummy)
                self._shapes[batch] = jax.tree.map(
                    lambda x: jax.ShapeDtypeStruct(np.shape(x), np.asarray(x).dtype), out)
        return self._shapes[batch]

    def __call__(self, grasps):
        """Simulate (N, 7) grasps on the host; returns the TrialResult as numpy arrays."""
        return self._simulate(np.asarray(check_grasps(grasps), dtype=np.float32))

    def _simulate(self, g: np.ndarray):
        if len(g) == 0:
            raise ValueError("no grasps to simulate")
        if self.cohort is not None:
            return self.cohort.simulate(self, g)
        return self.simulate_now(g)

    def simulate_now(self, g: np.ndarray, merged: bool = False):
        """The TrialResult (numpy) of grasps ``g`` (N >= 1, 7) float32, simulated here (not
        through a cohort). ``merged``: the calls of several runs (a cohort's), one bucketed
        call of up to ``max_bucket`` grasps instead of calls of ``batch_size``."""
        n = len(g)
        size = self.call_size(n, merged)
        # Padding rows are PAD_GRASP: trials are independent, so they change nothing.
        padded = pad_grasps(g, -(-n // size) * size)
        # MuJoCo C's trial runs on the host anyway: called directly, not through a callback.
        run = getattr(self.trial, "host", None) or (self._jitted if self.traceable else self.trial)
        parts = [jax.device_get(run(padded[i:i + size])) for i in range(0, len(padded), size)]
        with self._count_lock:
            self.num_trials += n
        return jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *parts)

    def outcomes(self, g: np.ndarray) -> np.ndarray:
        """The outcome codes (N,) of grasps ``g`` (N >= 1, 7) float32, simulated here in calls
        of up to ``max_bucket``: on MuJoCo C from the host's decisions alone (the same codes
        as the whole trial's, without its contacts and epsilon), otherwise the whole trial's.
        For tries whose outcome is all that counts (robustness)."""
        host = getattr(self.trial, "outcomes", None)
        if host is None:  # MJX, a caller's trial: the whole trial
            return np.asarray(self.simulate_now(g, merged=True).outcome)
        out = np.concatenate([host(g[i:i + self.max_bucket])
                              for i in range(0, len(g), self.max_bucket)])
        with self._count_lock:
            self.num_trials += len(g)
        return out

    def call_size(self, n: int, merged: bool = False) -> int:
        """The batch size of each trial call for ``n`` grasps (every call is padded to it);
        ``merged``: calls of several runs, not padded to ``batch_size``."""
        # MJX compiles per shape (minutes): merged calls keep its batch size.
        merged = merged and self.backend == "mujoco"
        size = min(n, self.max_bucket) if merged or not self.batch_size else self.batch_size
        return size if self.min_bucket is None else bucket_size(size, self.min_bucket)

    def callback_trial(self):
        """A jittable, vmappable ``(B, 7) -> TrialResult`` that runs this simulator on the host.

        Under ``vmap`` the batch axes are folded into one host call (``vmap_method=
        "expand_dims"``), so vmapping a per-chain density over C chains costs one rollout
        of C grasps. A :class:`HostTrial`: this simulator's id is an array, so the samplers
        built on it are the same program for every simulator whose results have the same
        shapes (every object with this gripper): a new object compiles no sampler.
        """
        if self._callback is None:
            leaves, treedef = jax.tree.flatten(self.result_shapes(1))
            if any(x.shape[:1] != (1,) for x in leaves):
                raise ValueError("every trial result field must have the leading batch axis")
            spec = (treedef, tuple((x.shape[1:], np.dtype(x.dtype)) for x in leaves))
            self._callback = HostTrial(np.asarray(self._token, np.int32), spec)
        return self._callback

    def logdensity(self, *, floor: float, lifted: bool = False, width: float = 0.05,
                   **options):
        """The grasp log-density on this trial through the host callback (:class:`GraspTarget`);
        ``options``: the other ``jg.density.grasp_logdensity`` arguments."""
        return GraspTarget(self).logdensity(floor=floor, lifted=lifted, width=width, **options)


_tokens = itertools.count()
_simulators = {}  # Simulator id -> weak reference (a HostTrial calls it by its id)
_ids_lock = threading.Lock()


def _host_call(token, grasps):
    """The host side of :class:`HostTrial`: the simulator with id ``token`` on ``grasps``."""
    sim = _simulators.get(int(np.asarray(token).reshape(-1)[0]), lambda: None)()
    if sim is None:
        raise RuntimeError("the Simulator of this sampler no longer exists")
    g = np.asarray(grasps, np.float32)
    lead = g.shape[:-1]
    res = sim._simulate(g.reshape(-1, 7))
    return jax.tree.map(lambda x: x.reshape(lead + x.shape[1:]), res)


@dataclass(frozen=True, eq=False)
class HostTrial:
    """``(B, 7) -> TrialResult`` of the simulator with id ``token``, run on the host through
    ``jax.pure_callback`` (:meth:`Simulator.callback_trial`).

    A pytree: ``token`` (an int32 array) is its leaf, ``spec`` (the result's structure and
    per-row shapes) its static part, so a sampler takes the simulator's id as an argument
    and one compiled sampler serves every simulator of the same result shapes.
    """

    token: object
    spec: tuple

    def __call__(self, grasps):
        grasps = jnp.asarray(grasps, jnp.float32)
        if grasps.ndim != 2 or grasps.shape[-1] != 7:
            raise ValueError(f"grasps must be (B, 7), got shape {grasps.shape}")
        treedef, rows = self.spec
        shapes = jax.tree.unflatten(treedef, [jax.ShapeDtypeStruct((grasps.shape[0], *s), d)
                                              for s, d in rows])
        return jax.pure_callback(_host_call, shapes, self.token, grasps,
                                 vmap_method="expand_dims")


jax.tree_util.register_pytree_node(
    HostTrial, lambda t: ((t.token,), t.spec), lambda spec, kids: HostTrial(kids[0], spec))


@dataclass(frozen=True)
class GraspTarget:
    """Where a sampler's trials run: ``sim.trial`` traced into the sampler (``traced``), or
    ``sim`` on the host through one callback per step (default).

    Equal arguments give equal (hashable) log-densities, so samplers rebuilt with new arrays
    (sketch, modes) reuse their compiled code.
    """

    sim: Simulator
    traced: bool = False

    def __post_init__(self):
        if self.traced and not self.sim.traceable:
            raise ValueError("a host-level trial (numpy in and out) can't be traced into the "
                             "sampler; it stays a host callback")

    @property
    def trial(self):
        return self.sim.trial if self.traced else self.sim.callback_trial()

    def logdensity(self, *, floor: float, lifted: bool = False, width: float = 0.05,
                   **options):
        """``log(w epsilon^power + floor)`` on the trial, ``g (7,) -> (log pi, aux)``; lifted to
        R^7 for Kameleon if asked (``jaxgrasp.mcmc.lift_quaternion`` with ``width``);
        ``options``: the other ``jg.density.grasp_logdensity`` arguments (slip weight, power,
        perturbed tries)."""
        fn = density.grasp_logdensity(self.trial, floor=float(floor), **options)
        return mcmc.lift_quaternion(fn, width=float(width)) if lifted else fn


def run_backend(backend, trial=None) -> str:
    """The resolved backend name a run records (``"mjx"`` or ``"mujoco"``, never ``"auto"``).

    ``"auto"`` with a :class:`Simulator` as ``trial``: that simulator's backend (it runs the
    physics); otherwise :func:`jaxgrasp.physics.resolve_backend`.
    """
    if backend == "auto" and isinstance(trial, Simulator):
        return trial.backend
    return resolve_backend(backend)


def as_simulator(obj, *, backend="auto", trial=None, batch_size=None,
                 min_bucket=MIN_BUCKET) -> Simulator:
    """``trial`` if it already is a Simulator, a new one around a callable ``trial``, else
    (``trial`` None) the process's :func:`shared_simulator` of ``obj``."""
    if isinstance(trial, Simulator):
        want = resolve_object(obj)
        if (trial.obj.name, trial.obj.content_hash) != (want.name, want.content_hash):
            raise ValueError(f"the Simulator passed as trial simulates {trial.obj.name!r}, "
                             f"not {want.name!r}")
        return trial
    if trial is None:
        return shared_simulator(obj, backend=backend, batch_size=batch_size,
                                min_bucket=min_bucket)
    return Simulator(obj, backend=backend, trial=trial, batch_size=batch_size,
                     min_bucket=min_bucket)


_shared = OrderedDict()  # (scene key, backend, batch_size, min_bucket) -> Simulator
_trials = {}  # (scene key, backend) -> (scene, trial), shared by every batch size
_shared_lock = threading.Lock()
_fingerprints = weakref.WeakKeyDictionary()  # GraspObject -> content digest


def object_fingerprint(obj) -> str:
    """A digest of everything a trial reads of a GraspObject: name, content hash, mesh,
    convex pieces and mass properties (objects built in code have no content hash)."""
    try:
        return _fingerprints[obj]
    except (KeyError, TypeError):
        pass
    h = hashlib.sha256(repr((obj.name, obj.content_hash, float(obj.mass),
                             float(obj.support_z), float(obj.max_radius))).encode())
    for a in (obj.com, obj.inertia, obj.mesh.vertices, obj.mesh.faces, *obj.pieces):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    digest = h.hexdigest()
    try:
        _fingerprints[obj] = digest
    except TypeError:  # an object without weak references: digested on every call
        pass
    return digest


def scene_key(obj) -> tuple:
    """What makes two trials the same: the object's content, the gripper and the protocol
    (a GraspObject or a name: the defaults :func:`jaxgrasp.physics.load_scene` uses)."""
    scene = obj if hasattr(obj, "obj") and hasattr(obj, "gripper") else None
    gripper = scene.gripper if scene is not None else physics.GripperParams()
    params = scene.params if scene is not None else physics.TrialParams()
    return object_fingerprint(resolve_object(obj)), gripper, params


def shared_simulator(obj, *, backend="auto", batch_size=None,
                     min_bucket=MIN_BUCKET) -> Simulator:
    """The process's Simulator of ``obj`` (GraspObject, Scene or name) for these arguments,
    built on first use.

    Equal content (:func:`scene_key`), backend, ``batch_size`` and ``min_bucket`` give the
    same Simulator, so the samplers compiled around its callback and its trial's JAX stages
    serve every later run; simulators of other batch sizes share its trial. At most
    :data:`MAX_SHARED` are kept (:func:`clear_shared` drops them all).
    """
    backend = resolve_backend(backend)
    key = scene_key(obj)
    sim_key = (key, backend, batch_size, min_bucket)
    with _shared_lock:  # one build per key when threads (a cohort's runs) ask together
        sim = _shared.get(sim_key)
        if sim is not None:
            _shared.move_to_end(sim_key)
            return sim
        if (key, backend) not in _trials:
            scene = obj if hasattr(obj, "gripper") else physics.load_scene(obj)
            _trials[key, backend] = scene, physics.make_trial(scene, backend=backend)
        scene, trial = _trials[key, backend]
        sim = Simulator(scene, backend=backend, trial=trial, batch_size=batch_size,
                        min_bucket=min_bucket)
        sim._traceable = True  # make_trial's trials trace (MuJoCo C through its callback)
        _shared[sim_key] = sim
        while len(_shared) > MAX_SHARED:
            (old_key, old_backend, *_), _old = _shared.popitem(last=False)
            if not any(k[:2] == (old_key, old_backend) for k in _shared):
                _trials.pop((old_key, old_backend), None)
        return sim


def clear_shared() -> None:
    """Forget the shared simulators and trials (the next run builds and compiles anew)."""
    with _shared_lock:
        _shared.clear()
        _trials.clear()
