"""Several learning runs at once, their trials merged into one host call per step.

A sampler reaches its trial through a host callback (:class:`~jaxgrasp.learn.sim.Simulator`),
so one run of C chains simulates C grasps per call: 8 chains leave MuJoCo C's threads and the
JAX tail mostly idle. A :class:`Cohort` runs several learning runs in threads of this process
and merges the trial calls that arrive together, from any run and any object, into one host
call: one leader thread simulates every run's grasps, one batch per object, and hands each run
its rows.

Why each member runs on its own CPU device: XLA runs one computation at a time per device, so
a sampler blocked in its callback, waiting for the others to arrive, would hold up the
samplers queued behind it (measured: two runs on one device deadlock). With
``--xla_force_host_platform_device_count`` set before JAX starts, member ``i`` runs on CPU
device ``i + 1``; device 0 stays free for the physics' own computations.

Trials are independent per row: a row's outcome does not depend on the rest of its batch, and
its epsilon only up to round-off (epsilon's runs are dealt to lanes across the batch;
``tests/learn/test_cohort.py`` checks both). A run merged with others therefore equals the run
alone bit for bit with a trial that is elementwise (tested), and up to that round-off with the
real trial, which can, rarely, turn an acceptance decision and let the chains part.
"""

import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import jax
import numpy as np

from jaxgrasp._xla import device_count_flag

__all__ = ["Cohort"]

#: Longest wait (seconds) of a trial call for the other members' calls before it runs with
#: those that came. Members step in lockstep once merged; a member busy elsewhere (compiling,
#: building its sketch) delays the others by this much per step. On 2 cores, 7 bench cells:
#: 0.02 s merged 14.9 trials per call, 0.3 s 24.7 and ran 1.5x faster (docs/design.md).
MAX_WAIT_S = 0.3


class _Request:
    __slots__ = ("sim", "grasps", "result", "error", "done")

    def __init__(self, sim, grasps):
        self.sim, self.grasps = sim, grasps
        self.result = self.error = None
        self.done = threading.Event()


class Cohort:
    """Runs up to ``members`` learning runs at once and merges their trial calls.

    Parameters
    ----------
    members : int
        Runs at once. Needs ``members + 1`` CPU devices (:func:`device_count_flag`).
    max_wait : float
        Seconds a trial call waits for the other members' calls (:data:`MAX_WAIT_S`).

    Use :meth:`attach` on each run's Simulator, then :meth:`run` the runs (or enter
    :meth:`member` in each thread that runs one)::

        os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"  # before JAX runs
        cohort = jg.learn.Cohort(3)
        sims = {o: cohort.attach(jg.learn.Simulator(o, batch_size=8)) for o in objs}
        results = cohort.run([partial(jg.learn.active, o, trial=sims[o], chains=8)
                              for o in objs])

    ``sizes`` counts the merged host calls by their number of grasps (``calls``: in all).
    """

    def __init__(self, members: int, *, max_wait: float = MAX_WAIT_S):
        if not isinstance(members, int) or members < 1:
            raise ValueError(f"members must be a positive int, got {members!r}")
        cpus = jax.devices("cpu")
        if len(cpus) < members + 1:
            raise ValueError(
                f"a cohort of {members} runs needs {members + 1} CPU devices (one per run, "
                f"device 0 for the physics), JAX has {len(cpus)}: set XLA_FLAGS="
                f"{device_count_flag(members)} before JAX starts")
        self.members, self.max_wait = members, float(max_wait)
        self.physics_device, self._free = cpus[0], list(cpus[1:members + 1])
        self._active = 0
        self._pending = []
        self._cond = threading.Condition()
        self.sizes = Counter()  # merged host calls by their number of grasps

    @property
    def calls(self) -> int:
        """Merged host calls so far."""
        return sum(self.sizes.values())

    def attach(self, sim):
        """Route ``sim``'s host calls through this cohort; returns ``sim``."""
        sim.cohort = self
        return sim

    @contextmanager
    def member(self):
        """This thread runs one member: its computations go to a device of its own, and the
        others' trial calls wait for its calls (up to ``max_wait``)."""
        with self._cond:
            if not self._free:
                raise RuntimeError(f"more than {self.members} members at once")
            device = self._free.pop(0)
            self._active += 1
        try:
            with jax.default_device(device):
                yield device
        finally:
            with self._cond:
                self._active -= 1
                # Lowest ids first: later members reuse the devices (and compiles) of earlier.
                self._free = sorted([*self._free, device], key=lambda d: d.id)
                self._cond.notify_all()  # the calls waiting for this member go now

    def run(self, tasks):
        """Run the zero-argument callables ``tasks`` (each one learning run), up to
        ``members`` at once, each in a member thread; their results in order (the first
        error is raised once all have finished)."""
        tasks = list(tasks)
        results, errors = [None] * len(tasks), [None] * len(tasks)
        todo = iter(range(len(tasks)))
        lock = threading.Lock()
        num_threads = min(self.members, len(tasks))
        # The first runs start together: a call made before the others are members would not
        # wait for them, so how much merges would depend on how fast threads start.
        started = threading.Barrier(num_threads)

        def worker():
            first = True
            while True:
                with lock:
                    i = next(todo, None)
                if i is None:
                    return
                try:
                    with self.member():
                        if first:
                            first = False
                            started.wait()
                        results[i] = tasks[i]()
                except BaseException as err:  # noqa: BLE001 - raised by the caller below
                    errors[i] = err

        threads = [threading.Thread(target=worker, name=f"jaxgrasp-cohort-{k}", daemon=True)
                   for k in range(num_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for err in errors:
            if err is not None:
                raise err
        return results

    def simulate(self, sim, grasps: np.ndarray):
        """``sim``'s TrialResult (numpy) of ``grasps`` (N, 7), simulated with the calls of
        the other members that arrive within ``max_wait`` (or until every member has one)."""
        req = _Request(sim, grasps)
        batch = None
        with self._cond:
            self._pending.append(req)
            self._cond.notify_all()
            deadline = time.monotonic() + self.max_wait
            while req in self._pending:
                left = deadline - time.monotonic()
                if len(self._pending) >= self._active or left <= 0:
                    batch, self._pending = self._pending, []
                    self.sizes[sum(len(r.grasps) for r in batch)] += 1  # under the lock
                    break
                self._cond.wait(left)
        if batch is not None:
            self._run(batch)
        req.done.wait()
        if req.error is not None:
            raise req.error
        return req.result

    def _run(self, batch):
        """Simulate a batch of requests: one call per simulator, rows handed back."""
        try:
            # Device 0 whichever thread leads: one compiled trial per batch size, not per device.
            with jax.default_device(self.physics_device):
                self._simulate_groups(batch)
        except BaseException as err:  # noqa: BLE001 - every waiting member gets it
            for r in batch:
                r.error = err
        finally:
            for r in batch:
                r.done.set()

    @staticmethod
    def _simulate_groups(batch):
        groups = {}
        for r in batch:
            groups.setdefault(id(r.sim), []).append(r)

        def simulate(reqs):
            sizes = [len(r.grasps) for r in reqs]
            res = reqs[0].sim.simulate_now(np.concatenate([r.grasps for r in reqs]),
                                           merged=True)
            offsets = np.cumsum([0, *sizes])
            for r, lo, hi in zip(reqs, offsets[:-1], offsets[1:], strict=True):
                r.result = jax.tree.map(lambda x, lo=lo, hi=hi: x[lo:hi], res)

        # One thread per further object: their engines (C threads, no GIL) and tails overlap.
        first, *rest = groups.values()
        if not rest:
            return simulate(first)
        with ThreadPoolExecutor(len(rest)) as pool:
            futures = [pool.submit(simulate, reqs) for reqs in rest]
            simulate(first)
            for f in futures:
                f.result()
