"""Test-wide setup: the persistent compilation cache (MJX scenes are expensive to compile),
XLA's backend at -O0 (compiles dominate the suite), and headless rendering (MuJoCo picks its
GL backend when first imported, by any test)."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
# Most tests compile far more than they run: XLA's backend at -O0 compiles faster (cold cache,
# idle 2-core machine: the MJX trial tests 106 -> 84 s); what tests assert does not depend on
# it. XLA_FLAGS is part of JAX's cache key, so these executables never reach a benchmark that
# shares the cache directory. The sampler tests run more than they compile: `xla_optimized`.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_backend_optimization_level=0").strip()

import pytest

from jaxgrasp._cache import enable_compilation_cache

REPO = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR", REPO / ".cache" / "jax"))


@pytest.fixture
def xla_optimized(monkeypatch):
    """XLA's backend at its default -O2 for this test's compiles (the sampler tests: 400 chains
    x 300 steps run twice as fast, and their cold suite takes 115 s against 130 s at -O0). An
    override per compile, which JAX puts in the cache key; without that private hook (another
    JAX version) the test runs at -O0, slower and the same."""
    from jax._src import compiler  # why: the per-compile options have no public switch

    real = getattr(compiler, "get_compile_options", None)
    if real is None:
        return

    def optimized(*args, env_options_overrides=None, **kwargs):
        options = {**(env_options_overrides or {}), "xla_backend_optimization_level": 2}
        return real(*args, env_options_overrides=options, **kwargs)

    monkeypatch.setattr(compiler, "get_compile_options", optimized)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def load_benchmark():
    """``load_benchmark(name)`` imports ``benchmarks/<name>.py`` (not a package) as a module,
    for tests that reuse a benchmark's pieces."""
    import importlib.util

    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"benchmarks_{name}",
                                                      REPO / "benchmarks" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture(scope="session")
def kill_at_second_run():
    """``kill_at_second_run("pkg.module", args, cwd=, env=)``: run ``pkg.module.main(args)`` in
    a subprocess that stops, after writing it, at the first chain checkpoint of its second
    learning run (runs go one at a time) and says "killable" on the real stdout (a run's own
    output may be redirected); kill it there with SIGKILL, not after a sleep, and return its
    exit status (``-SIGKILL`` when it was killed, anything else if it finished first)."""
    def run(module: str, args, *, cwd, env) -> int:
        source = textwrap.dedent(f"""
            import sys, time
            from jaxgrasp.learn import chains
            real, seen = chains.save_checkpoint, []

            def save(checkpoint, step, hist, state):
                real(checkpoint, step, hist, state)
                if str(checkpoint.dir) not in seen:
                    seen.append(str(checkpoint.dir))
                if len(seen) == 2:
                    print("killable", file=sys.__stdout__, flush=True)
                    time.sleep(3600)

            chains.save_checkpoint = save
            from {module} import main
            sys.exit(main(sys.argv[1:]))
        """)
        proc = subprocess.Popen([sys.executable, "-c", source, *args], cwd=cwd, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        for line in proc.stdout:
            if line.strip() == "killable":
                proc.send_signal(signal.SIGKILL)
                break
        proc.wait(timeout=60)
        return proc.returncode
    return run


@pytest.fixture
def break_library(monkeypatch):
    """``break_library(module, name, value)``: replace a function of the library's own kernel
    for one test (a companion that must fail). Compiled programs are dropped before and after,
    so the broken code is traced afresh and never reused by a later test in this process."""
    import jax

    jax.clear_caches()
    yield monkeypatch.setattr
    monkeypatch.undo()
    jax.clear_caches()


#: Only for a hang the stall check cannot see (threads spinning forever): it never decides a
#: pass or a fail on a machine that is merely slow.
BACKSTOP_S = 3600


@pytest.fixture
def on_two_pool_threads(tmp_path):
    """``on_two_pool_threads(setup, call, repeats, stall_s)`` runs the Python ``setup``, then
    ``call`` once, then ``call`` ``repeats`` times on each of two threads at once, in a
    subprocess whose XLA pool has 2 threads (``PJRT_NPROC=2``, as on a 2-core machine), and
    asserts both threads finish. A runtime that blocks in the pool it shares hangs there: the
    check fails when the threads make no progress (no call finished, no CPU time spent) for
    ``stall_s`` seconds. A busy machine slows the calls down but never stops them, so only a
    real deadlock fails (``tests/test_checks.py`` shows one does)."""
    import subprocess
    import sys
    import textwrap

    def run(setup: str, call: str, repeats: int, stall_s: float):
        code = textwrap.dedent(setup) + textwrap.dedent(f"""
            import os, threading, time
            {call}
            done = [0]
            def loop():
                for _ in range({repeats}):
                    {call}
                    done[0] += 1
            threads = [threading.Thread(target=loop, daemon=True) for _ in range(2)]
            [t.start() for t in threads]
            last, quiet_since = (done[0], time.process_time()), time.monotonic()
            while any(t.is_alive() for t in threads):
                threads[0].join(1.0)
                now = (done[0], time.process_time())
                if now[0] != last[0] or now[1] - last[1] > 0.5:  # progress: calls or CPU
                    last, quiet_since = now, time.monotonic()
                elif time.monotonic() - quiet_since > {stall_s}:
                    break
            print("alive", sum(t.is_alive() for t in threads), flush=True)
            os._exit(0)
            """)
        proc = subprocess.run([sys.executable, "-c", code],
                              env={**os.environ, "PJRT_NPROC": "2"}, capture_output=True,
                              text=True, cwd=tmp_path, timeout=BACKSTOP_S)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert "alive 0" in proc.stdout, proc.stdout + proc.stderr[-2000:]

    return run
