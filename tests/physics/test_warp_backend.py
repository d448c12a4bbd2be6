"""The optional MJX-Warp backend (``backend="mjx-warp"``, extra ``warp``) and ``"auto"``.

The fast tests need no warp-lang; the agreement test skips without it and is slow (Warp
compiles its kernels for the CPU on first use: ~1.5 min, then cached in ~/.cache/warp).
"""

import subprocess
import sys

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.physics import inputs, warp_backend
from jaxgrasp.physics.inputs import resolve_backend

DOWN = [0.0, 1.0, 0.0, 0.0]  # top-down approach, pads close along the box's y
GRASPS = np.array([
    [0.0, 0.0, 0.085, *DOWN],  # success
    [0.0, 0.0, 0.05, *DOWN],  # palm inside the box: collision
    [-0.012, 0.0, 0.05, 0.7071, 0.0, 0.7071, 0.0],  # side grasp: success
    [0.15, 0.0, 0.05, *DOWN],  # beside: miss
    [0.008, 0.01, 0.09, *DOWN],
], np.float32)


def test_backend_names():
    assert "mjx-warp" in inputs.BACKENDS
    for name in inputs.BACKENDS:
        assert resolve_backend(name) == name
    with pytest.raises(ValueError, match="mjx-warp"):
        resolve_backend("warp")


def test_auto_takes_the_fastest_measured_available_backend(monkeypatch):
    """"auto" ranks the measured trials/s of the device kind, skips what is not installed,
    and falls back to MJX on a kind without measurements."""
    table = {"cpu": {"mujoco": 400.0, "mjx": 13.0, "mjx-warp": 2.0},
             "gpu": {"mjx-warp": 9000.0, "mjx": 5000.0, "mujoco": 400.0}}
    monkeypatch.setattr(inputs, "MEASURED_TRIALS_PER_S", table)
    kind = {"value": "cpu"}
    monkeypatch.setattr(inputs.jax, "default_backend", lambda: kind["value"])
    assert resolve_backend("auto") == "mujoco"
    kind["value"] = "gpu"
    monkeypatch.setattr(inputs, "_available", lambda b: True)
    assert resolve_backend("auto") == "mjx-warp"
    monkeypatch.setattr(inputs, "_available", lambda b: b != "mjx-warp")
    assert resolve_backend("auto") == "mjx"
    kind["value"] = "tpu"
    assert resolve_backend("auto") == inputs.UNMEASURED_DEFAULT == "mjx"


def test_shipped_table_picks_c_on_a_cpu():
    assert max(inputs.MEASURED_TRIALS_PER_S["cpu"], key=inputs.MEASURED_TRIALS_PER_S["cpu"].get) \
        == "mujoco"


def test_missing_warp_is_a_clear_import_error(monkeypatch):
    monkeypatch.setattr(warp_backend, "warp_available", lambda: False)
    scene = jg.physics.load_scene(jg.objects.make_box())
    with pytest.raises(ImportError, match=r"jaxgrasp\[warp\]"):
        jg.physics.make_trial(scene, backend="mjx-warp")


@pytest.mark.slow
def test_warp_agrees_with_c_on_the_box():
    """Mixed outcomes on the box: MJX-Warp and MuJoCo C agree on every outcome, epsilon
    within 1 %; B = 5 is padded to 8 and sliced back."""
    pytest.importorskip("warp")
    scene = jg.physics.load_scene(jg.objects.make_box(np.array([0.03, 0.03, 0.05]), 0.2))
    rw = jg.physics.make_trial(scene, backend="mjx-warp")(GRASPS[:5])
    rc = jg.physics.make_trial(scene, backend="mujoco")(GRASPS[:5])
    assert rw.outcome.shape == (5,)
    np.testing.assert_array_equal(np.asarray(rw.outcome), np.asarray(rc.outcome))
    np.testing.assert_allclose(np.asarray(rw.epsilon), np.asarray(rc.epsilon), rtol=0.01,
                               atol=1e-4)


def test_fold_vmap_makes_one_call_of_every_row():
    """``_batching.fold_vmap``: an outer vmap (nested too, under jit) becomes one call of the
    trial on all rows, split back; the same values as one call per member; concrete calls
    go straight to the trial."""
    import jax
    import jax.numpy as jnp

    seen = []

    def trial(g):  # a batch-sized stand-in: rejects anything but (B, 7)
        seen.append(tuple(g.shape))
        assert g.ndim == 2
        return jnp.sum(g, axis=1), g[:, :3] * 2.0

    from jaxgrasp._batching import fold_vmap

    folded = fold_vmap(trial, event_ndim=1)
    g = np.random.default_rng(0).random((2, 3, 4, 7)).astype(np.float32)
    out = jax.jit(jax.vmap(jax.vmap(folded)))(g)
    assert (24, 7) in seen and out[0].shape == (2, 3, 4) and out[1].shape == (2, 3, 4, 3)
    for i in range(2):
        for j in range(3):
            ref = trial(jnp.asarray(g[i, j]))
            np.testing.assert_allclose(out[0][i, j], ref[0], rtol=1e-6)
            np.testing.assert_allclose(out[1][i, j], ref[1], rtol=1e-6)
    seen.clear()
    folded(g[0, 0])
    assert seen == [(4, 7)]


@pytest.mark.slow
def test_warp_trial_under_jit_and_vmap():
    """The MJX-Warp trial traced twice at one batch size (jit, then vmap over 4 chains of 2
    grasps) keeps no tracer in its per-size Warp data, and the vmapped call gives the results
    of one call on all 8 grasps: with 16 contact slots per trial the 8 grasps fit one call's
    buffer, not the 2-grasp buffer a plain vmap would share among the 4 members."""
    pytest.importorskip("warp")
    import jax

    scene = jg.physics.load_scene(jg.objects.make_box(np.array([0.03, 0.03, 0.05]), 0.2))
    trial = warp_backend.make_warp_trial(scene, max_contacts=16)
    g = GRASPS[[0, 2, 4, 0, 2, 4, 0, 2]].reshape(4, 2, 7)
    jax.block_until_ready(jax.jit(trial)(g[0]))
    vm = jax.jit(jax.vmap(trial))(g)
    flat = trial(g.reshape(8, 7))
    assert vm.outcome.shape == (4, 2) and (np.asarray(flat.outcome) == 0).all()
    np.testing.assert_array_equal(np.asarray(vm.outcome).ravel(), np.asarray(flat.outcome))
    np.testing.assert_allclose(np.asarray(vm.epsilon).ravel(), np.asarray(flat.epsilon),
                               rtol=1e-4, atol=1e-6)


def test_importing_the_physics_prints_nothing():
    """mujoco.mjx prints "Failed to import warp" at import when warp-lang is absent; the
    physics imports it with that notice kept off stdout (warp installed or not: silent)."""
    out = subprocess.run([sys.executable, "-c", "import jaxgrasp.physics"], capture_output=True,
                         text=True, check=True)
    assert out.stdout == ""
    # The companion: mujoco.mjx alone prints the notice where Warp is missing.
    if not warp_backend.warp_available():
        raw = subprocess.run([sys.executable, "-c", "import mujoco.mjx"], capture_output=True,
                             text=True, check=True)
        assert "Failed to import warp" in raw.stdout
