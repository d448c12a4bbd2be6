"""Agreement of the MJX and MuJoCo C grasp trials on fixed pose sets.

    .venv/bin/python benchmarks/backend_agreement.py [--objects pitcher pan plate]
        [--num-poses 512] [--out bench_out/backend_agreement.json]

For each object, ``--num-poses`` poses (fixed seed, independent of both backends, see
:func:`agreement_poses`) run through both backends; reports the outcome confusion matrix,
the outcome agreement, and the relative epsilon difference where both succeed
(``|eps_mjx - eps_c| / max(eps_mjx, eps_c)``), plus every disagreeing pose with both
backends' displacement and contact counts, so disagreements can be explained.
Targets: agreement >= 95 %, epsilon within 10 % where both succeed.
"""

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from jaxgrasp.learn.setup.antipodal import ray_hits


def _rotation_to_quat(R):
    """(N, 3, 3) rotation matrices -> (N, 4) quaternions (w, x, y, z)."""
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(R).as_quat()
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)


def _first_hit(tri, origin, direction):
    """Distance to the first triangle hit along each ray (inf if none)."""
    return ray_hits(origin, direction, tri, max_hits=1)[0][:, 0]


def candidate_poses(obj, n, seed=0, surface_fraction=0.8, reach=0.04):
    """Candidate poses, drawn without running any physics.

    ``surface_fraction`` of them are wall-sliding grasps: at a random surface point with
    normal ``n``, closing axis (grasp ``y``) ``= n``, approach (grasp ``z``) uniform
    perpendicular to ``n``; the grasp center sits ``t ~ U(0, 2 cm)`` beyond the first surface
    hit of the approach line through a point 0.5-3 mm inside the wall, so the palm stops
    short of the rim/edge and the pads (4 cm long) straddle the wall: rims, walls and
    handles give successes and slips, bulky parts misses or collisions. The rest are
    uniform poses near the object (mostly collisions and misses).
    """
    rng = np.random.default_rng(seed)
    n_surf = int(round(surface_fraction * n))
    pts, face = obj.mesh.sample(n_surf, return_index=True, seed=int(rng.integers(2**31)))
    y = np.asarray(obj.mesh.face_normals)[face]  # close across the local wall
    helper = rng.normal(size=(n_surf, 3))
    z = helper - np.sum(helper * y, axis=1, keepdims=True) * y
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    # Slide in along the wall: first surface hit on the line through a point just inside it.
    target = pts - rng.uniform(0.0005, 0.003, (n_surf, 1)) * y
    origin = target - z  # 1 m back along the approach: outside the object
    first = np.minimum(_first_hit(obj.mesh.triangles, origin, z), 1.0)
    hit = origin + first[:, None] * z
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=2)  # columns: grasp axes in the object frame
    center = hit + rng.uniform(0.0, 0.02, (n_surf, 1)) * z
    surf = np.concatenate([center, _rotation_to_quat(R)], axis=1)

    lo, hi = np.asarray(obj.mesh.bounds, float)
    lo, hi = lo - reach, hi + reach
    lo[2] = max(lo[2], obj.support_z)
    m = n - n_surf
    q = rng.normal(size=(m, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    uni = np.concatenate([rng.uniform(lo, hi, (m, 3)), q], axis=1)
    poses = np.concatenate([surf, uni]).astype(np.float32)
    return poses[rng.permutation(n)]


def agreement_poses(obj, n, seed=0, collision_fraction=0.25, placement=None):
    """A fixed set of ``n`` poses with mixed outcomes.

    The convex pieces of thin-walled objects are thicker than the mesh walls, so most
    candidates (:func:`candidate_poses`) collide at placement. The set is therefore stratified
    on the *placement* test only (no rollout): ``collision_fraction`` of the poses collide,
    the rest do not, according to ``placement(poses) -> (qpos, collision)`` (default: the
    MuJoCo C engine's collision pass; the rollout outcomes stay unselected, so the
    success/slip/miss comparison is unbiased; the collision agreement is measured on both
    strata).
    """
    if placement is None:
        raise ValueError("agreement_poses needs a placement function (e.g. MujocoEngine.place)")
    pool, colliding = np.zeros((0, 7), np.float32), np.zeros(0, bool)
    n_free, n_coll = n - int(round(collision_fraction * n)), int(round(collision_fraction * n))
    for k in range(50):
        if (~colliding).sum() >= n_free and colliding.sum() >= n_coll:
            break
        cand = candidate_poses(obj, 4 * n, seed=seed * 1000 + k)
        pool = np.concatenate([pool, cand])
        colliding = np.concatenate([colliding, placement(cand)[1]])
    free, coll = np.flatnonzero(~colliding)[:n_free], np.flatnonzero(colliding)[:n_coll]
    if free.size < n_free:
        raise ValueError(f"only {free.size} non-colliding candidates for {obj.name!r}")
    idx = np.concatenate([free, coll])
    return pool[idx[np.random.default_rng(seed).permutation(idx.size)]]


def compare(res_mjx, res_c, eps_rtol=0.10):
    """Agreement statistics of two TrialResults (numpy-convertible) on the same poses."""
    from jaxgrasp.physics import Outcome

    om, oc = np.asarray(res_mjx.outcome), np.asarray(res_c.outcome)
    em, ec = np.asarray(res_mjx.epsilon, float), np.asarray(res_c.epsilon, float)
    conf = np.zeros((4, 4), int)
    np.add.at(conf, (om, oc), 1)
    both = (om == Outcome.SUCCESS) & (oc == Outcome.SUCCESS)
    denom = np.maximum(np.maximum(em, ec), 1e-12)
    rel = np.where(both, np.abs(em - ec) / denom, 0.0)
    both_pos = both & (np.maximum(em, ec) > 0)
    return {
        "n": int(om.size),
        "agreement": float(np.mean(om == oc)),
        "confusion_mjx_rows_c_cols": conf.tolist(),
        "labels": [o.name for o in Outcome],
        "shares_mjx": {o.name: float(np.mean(om == o)) for o in Outcome},
        "shares_c": {o.name: float(np.mean(oc == o)) for o in Outcome},
        "both_success": int(both.sum()),
        "eps_both_zero": int((both & ~both_pos).sum()),
        "eps_rel_diff_max": float(rel.max()) if both.any() else 0.0,
        "eps_rel_diff_median": float(np.median(rel[both])) if both.any() else 0.0,
        "eps_within_tol": float(np.mean(rel[both] <= eps_rtol)) if both.any() else 1.0,
        "eps_rtol": eps_rtol,
        "unstable_mjx": int(np.asarray(res_mjx.unstable).sum()),
        "unstable_c": int(np.asarray(res_c.unstable).sum()),
    }


def disagreements(poses, res_mjx, res_c, eps_rtol=0.10):
    """Per-pose details of outcome or epsilon disagreements."""
    om, oc = np.asarray(res_mjx.outcome), np.asarray(res_c.outcome)
    em, ec = np.asarray(res_mjx.epsilon, float), np.asarray(res_c.epsilon, float)
    rel = np.abs(em - ec) / np.maximum(np.maximum(em, ec), 1e-12)
    bad = (om != oc) | ((om == 0) & (oc == 0) & (rel > eps_rtol))
    rows = []
    for i in np.flatnonzero(bad):
        rows.append(
            {
                "index": int(i),
                "pose": [round(float(v), 5) for v in poses[i]],
                "outcome_mjx": int(om[i]),
                "outcome_c": int(oc[i]),
                "eps_mjx": round(float(em[i]), 5),
                "eps_c": round(float(ec[i]), 5),
                "disp_mjx": round(float(np.asarray(res_mjx.displacement)[i]), 5),
                "disp_c": round(float(np.asarray(res_c.displacement)[i]), 5),
                "ncontacts_mjx": int(np.asarray(res_mjx.contact_mask)[i].sum()),
                "ncontacts_c": int(np.asarray(res_c.contact_mask)[i].sum()),
                "pad_contact_mjx": np.asarray(res_mjx.pad_contact)[i].tolist(),
                "pad_contact_c": np.asarray(res_c.pad_contact)[i].tolist(),
            }
        )
    return rows


def pieces_near(engine, poses):
    """How many convex pieces each gripper box is within ``contact_tol`` of, over every state
    of the C rollouts of the non-colliding poses: {geom name: histogram}. Justifies
    ``TrialParams.pieces_per_pad`` / ``pieces_per_palm`` (MJX rollouts collide each box
    with only that many nearest pieces)."""
    import mujoco

    scene = engine.scene
    qpos, col = engine.place(poses)
    states = engine.rollout(qpos[~col])
    m, d = engine.m_contact, mujoco.MjData(engine.m_contact)  # pads carry the margin
    pieces = set(scene.ids.layout.piece_geoms)
    boxes = (*scene.ids.pad_geoms, scene.ids.palm_geom)
    hist = {b: np.zeros(len(pieces) + 1, int) for b in boxes}
    for q in states[:, :, 1 : 1 + engine.nq].reshape(-1, engine.nq):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        g, dist = np.array(d.contact.geom[: d.ncon]), np.array(d.contact.dist[: d.ncon])
        for b in boxes:
            on = (dist < scene.params.contact_tol) & (g == b).any(axis=1)
            hist[b][len(set(g[on].ravel()) & pieces)] += 1
    return {m.geom(b).name: np.trim_zeros(h, "b").tolist() for b, h in hist.items()}


def run_batched(trial, poses, batch):
    """Run a trial on poses in fixed-size batches (one compilation); pads the last batch."""
    import jax

    from jaxgrasp.physics import TrialResult

    n = poses.shape[0]
    outs = []
    for s in range(0, n, batch):
        g = poses[s : s + batch]
        pad = batch - g.shape[0]
        if pad:
            g = np.concatenate([g, np.repeat(g[-1:], pad, axis=0)])
        r = jax.block_until_ready(trial(g))
        outs.append(jax.tree.map(lambda x, k=batch - pad: np.asarray(x)[:k], r))
    return TrialResult(*(np.concatenate(f) for f in zip(*outs, strict=True)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", nargs="+", default=["pitcher", "pan", "plate"])
    ap.add_argument("--num-poses", type=int, default=512)
    ap.add_argument("--batch", type=int, default=128, help="C backend batch size")
    ap.add_argument("--mjx-batch", type=int, default=1, help="MJX (or --other) batch size")
    ap.add_argument("--other", default="mjx", choices=["mjx", "mjx-warp"],
                    help="the backend compared with MuJoCo C (mjx-warp: the optional extra)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench_out/backend_agreement.json")
    args = ap.parse_args(argv)

    import jax
    import mujoco

    import jaxgrasp as jg
    from jaxgrasp.physics import load_scene, make_trial

    jg.enable_compilation_cache()
    result = {
        "num_poses": args.num_poses,
        "seed": args.seed,
        "objects": {},
        "device": jax.devices()[0].device_kind,
        "platform": platform.platform(),
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
    }
    for name in args.objects:
        obj = jg.objects.load(name)
        scene = load_scene(obj)
        trial_c = make_trial(scene, backend="mujoco")
        poses = agreement_poses(obj, args.num_poses, args.seed, placement=trial_c.engine.place)
        t = time.perf_counter()
        res_c = run_batched(trial_c, poses, args.batch)
        t_c = time.perf_counter() - t
        t = time.perf_counter()
        # B = 1 (default): the pure trial skips colliding rollouts under lax.cond, and on a CPU
        # a vmapped MJX batch costs more per trial than single trials (benchmarks/throughput.py).
        trial_m = make_trial(scene, backend=args.other)
        res_m = run_batched(trial_m, poses, args.mjx_batch)
        t_m = time.perf_counter() - t
        t = time.perf_counter()
        run_batched(trial_m, poses, args.mjx_batch)
        t_m2 = time.perf_counter() - t
        stats = compare(res_m, res_c)
        stats["other"] = args.other  # the "mjx" fields below hold this backend's numbers
        stats["wall_s_incl_compile"] = {args.other: round(t_m, 1), "mujoco": round(t_c, 1)}
        stats["trials_per_s_warm"] = {args.other: round(len(poses) / t_m2, 2)}
        stats["pieces_within_contact_tol_hist"] = pieces_near(trial_c.engine, poses)
        stats["disagreements"] = disagreements(poses, res_m, res_c)
        result["objects"][name] = stats
        print(name, {k: v for k, v in stats.items() if k != "disagreements"}, flush=True)
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    print("wrote", path)


if __name__ == "__main__":
    main()
