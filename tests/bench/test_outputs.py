"""What the bench's outputs say: claim verdicts only where a test passes, the run's own wall
time counted once, throughput of the run's backend only, impossible speed ratios flagged.

Fakes only (no physics): tables are built from per-run counts, learning runs and simulators
are replaced, timings are measured on fakes that take milliseconds.
"""

import json

import jsonschema
import numpy as np
import pytest

from jaxgrasp.bench import cli, paper, plan, profiles, report, run, schema, tables
from jaxgrasp.learn.evaluate.hold import PoseNoise, Robustness
from jaxgrasp.learn.files.export import select_grasps
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos

OUT = paper.OUTCOMES


def cell(successes, proposals=16, collisions=None):
    """A table cell from each run's successes (the rest misses, or collisions when given)."""
    rows = []
    for i, s in enumerate(successes):
        c = 0 if collisions is None else collisions[i]
        rows.append([s, 0, c, proposals - s - c])
    return tables.make_cell(np.array(rows), proposals)


def claims_of(tbl):
    return {c["id"]: c for c in paper.evaluate_claims({"active": {}, "transfer": {}, **tbl})}


# --------------------------------------------------------------------------------------------
# 1. REPRODUCED only where the claim's test passes.


def test_a_larger_point_estimate_without_a_passing_test_is_not_shown():
    """The smoke run's case: 2 chains of 16, biased 9 vs random 7.5 successes per run (56.2 %
    vs 46.9 %): the larger point estimate alone is not a reproduction."""
    biased, rand = cell([8, 10]), cell([7, 8])
    c = claims_of({"active": {"pitcher": {"kameleon_darting_biased": biased,
                                          "kameleon_darting_random": rand}}})[
        "biased_beats_random"]
    assert c["ours"] is True  # the point estimates agree with the paper ...
    assert c["reproduced"] is False
    assert c["p_value"] >= paper.ALPHA  # ... the test does not pass
    assert c["verdict"] == f"not shown (p = {c['p_value']:.2g})"
    assert "[not shown (p = " in tables.render_claims_text([c])
    assert f"not shown (p = {c['p_value']:.2g})" in tables.render_claims_markdown([c])
    # Eight chains each, clearly apart: the test passes and the p-value is printed.
    biased, rand = cell([9, 10, 9, 11, 10, 9, 12, 10]), cell([3, 4, 2, 3, 5, 4, 3, 2])
    c = claims_of({"active": {"pitcher": {"kameleon_darting_biased": biased,
                                          "kameleon_darting_random": rand}}})[
        "biased_beats_random"]
    assert c["reproduced"] is True and c["p_value"] < paper.ALPHA
    assert c["verdict"] == f"REPRODUCED (p = {c['p_value']:.2g})"


def test_every_pair_of_a_claim_must_pass():
    """A claim over several objects is shown only when each pair's test passes (the largest
    p decides)."""
    strong, weak = cell([9, 10, 9, 11, 10, 9, 12, 10]), cell([3, 4, 2, 3, 5, 4, 3, 2])
    rows = {o: {"kameleon_darting_random": strong, "random_walk": weak}
            for o in ("pitcher", "pan")}
    rows["plate"] = {"kameleon_darting_random": cell([5, 4, 6, 5, 4, 5, 6, 4]),
                     "random_walk": cell([4, 5, 5, 4, 6, 4, 5, 5])}
    c = claims_of({"active": rows})["kameleon_random_beats_rw"]
    assert c["ours"] is True and c["reproduced"] is False
    assert c["p_value"] == pytest.approx(paper._rank_p(rows["plate"]["kameleon_darting_random"],
                                                       rows["plate"]["random_walk"], "success"))
    assert c["verdict"].startswith("not shown (p = ")


def test_rank_test_is_exact_with_tied_chains():
    """Three chains at 1 success vs three at 0: one arrangement in C(6, 3) = 20 is as
    extreme, p = 0.05 (not < 0.05); scipy's normal approximation under ties says 0.023."""
    assert paper._rank_p(cell([1, 1, 1]), cell([0, 0, 0]), "success") == pytest.approx(0.05)
    assert paper._rank_p(cell([1, 1]), cell([0, 0]), "success") == pytest.approx(1 / 6)
    c = claims_of({"transfer": {"transfer_a": {"tall_pitcher": {
        "target": cell([1, 1, 1]), "source": cell([0, 0, 0])}}}})["target_modes_beat_source"]
    assert c["ours"] is True and c["reproduced"] is False


def test_finds_grasps_needs_a_success_rate_shown_above_the_minimum():
    """One success in 120 proposals is not "finds grasps"; a rate well above 1 % in every
    chain is."""
    one = cell([1, 0, 0, 0], proposals=120)
    rows = {"pitcher": {"kameleon_darting_random": one, "kameleon_darting_biased": one}}
    c = claims_of({"active": rows})["active_finds_grasps"]
    assert c["ours"] is True  # a success was seen ...
    assert c["reproduced"] is False  # ... but no evidence of a rate > 1 %
    assert c["p_value"] > 0.5
    assert c["verdict"] == f"not shown (p = {c['p_value']:.2g})"
    many = cell([9, 11, 8, 10], proposals=120)
    rows = {"pitcher": {"kameleon_darting_random": many, "kameleon_darting_biased": many}}
    c = claims_of({"active": rows})["active_finds_grasps"]
    assert c["reproduced"] is True and c["p_value"] < paper.ALPHA
    # One cell of the claim without evidence: not shown.
    rows["pitcher"]["kameleon_darting_random"] = one
    assert claims_of({"active": rows})["active_finds_grasps"]["reproduced"] is False
    # A single chain admits no test (proposals of one chain are not independent).
    rows = {"pitcher": {"kameleon_darting_biased": cell([60], proposals=120)}}
    c = claims_of({"active": rows})["active_finds_grasps"]
    assert c["p_value"] is None and c["reproduced"] is False
    assert c["verdict"].startswith("not shown (no test")


def test_schema_requires_verdict_fields_and_rejects_untested_reproductions(tmp_path):
    profile = profiles.get_profile("smoke").with_overrides(chains=2)
    tbl = {"active": {"pitcher": {"kameleon_darting_biased": cell([8, 10]),
                                  "kameleon_darting_random": cell([7, 8]),
                                  "random_walk": cell([0, 1])}}, "transfer": {}}
    res = report.build_results(profile, "mujoco", tbl, {"total_s": 1.0, "experiments": {}}, {},
                               [], complete=True)
    schema.validate(res)
    claims = {c["id"]: c for c in res["comparison"]["claims"]}
    for c in claims.values():
        assert {"p_value", "alpha", "test", "verdict"} <= set(c)
        assert c["reproduced"] is not True or c["p_value"] < c["alpha"]
    bad = json.loads(json.dumps(res))
    c = next(c for c in bad["comparison"]["claims"] if c["id"] == "biased_beats_random")
    c["reproduced"], c["verdict"] = True, "REPRODUCED (p = 0.33)"
    with pytest.raises(ValueError, match="reproduced"):
        schema.validate(bad)
    bad = json.loads(json.dumps(res))
    del bad["comparison"]["claims"][0]["p_value"]
    with pytest.raises(jsonschema.ValidationError):
        schema.validate(bad)
    report.write_outputs(tmp_path, res, profile)
    md = (tmp_path / "tables.md").read_text()
    assert "not shown (p = " in md and "α = 0.05" in md


# --------------------------------------------------------------------------------------------
# 2. The run's wall time: its experiments' own seconds and setup, each counted once.


def fake_result(c, profile):
    rng = np.random.default_rng(len(c.id))
    steps, chains = profile.proposals, profile.chains
    outcomes = rng.choice(4, size=(steps, chains)).astype(np.int8)
    pos = rng.normal(0.0, 0.05, size=(steps, chains, 7)).astype(np.float32)
    pos[..., 3] += 1.0
    return LearnResult(
        object_name=c.obj, object_hash="0" * 16, workflow=c.table,
        method="random_walk" if c.column == "random_walk" else "kameleon_darting",
        sketch="biased", modes_kind="demos", seed=plan.cell_seed(profile.seed, c.row_id),
        backend="mujoco", params=plan.learn_params(profile), positions=pos,
        proposals=pos + 0.01, outcomes=outcomes,
        epsilons=rng.random((steps, chains)).astype(np.float32),
        accepted=rng.random((steps, chains)) < 0.3, is_jump=rng.random((steps, chains)) < 0.4,
        initial_positions=pos[0], modes=pos[0, :3].astype(float),
        sketch_points=pos[:, 0].astype(float), demos=Demos(pos[0, :3].astype(float), None),
        info={"physics": plan.physics_key()})


COMPILE_S = 2.5


class FakeSims:
    """Stands in for ``run.Simulators``: "compiles" each (object, backend) in COMPILE_S."""

    def __init__(self, backend, chains, bar=None):
        self.backend, self.compile_s, self.asked = backend, {}, []

    def __call__(self, name, backend=None):
        key = (name, backend or self.backend)
        self.asked.append(key)
        self.compile_s.setdefault(key, COMPILE_S)
        return object()


def saved_smoke_run(tmp_path):
    """``(profile, out, cells)``: a fake result saved for every cell of the smoke profile."""
    profile = profiles.get_profile("smoke")
    out = tmp_path / "bench"
    cells = plan.plan(profile, out)
    for c in cells:
        fake_result(c, profile).save(c.path)
    return profile, out, cells


def timings_of(out):
    return json.loads((out / "results.json").read_text())["timings"]


def test_wall_time_counts_each_experiment_and_setup_once(tmp_path, monkeypatch):
    profile, out, cells = saved_smoke_run(tmp_path)
    ran = []

    def fake_run_cell(c, profile, *a, **k):
        ran.append(c.id)
        return fake_result(c, profile)

    monkeypatch.setattr(run, "run_cell", fake_run_cell)
    monkeypatch.setattr(run, "Simulators", FakeSims)
    args = ["--profile", "smoke", "--out", str(out), "--no-figures", "--no-throughput",
            "--quiet", "--backend", "mujoco", "--jobs", "1"]
    # A resume that runs one experiment: its time plus compiling its object's trial.
    target = next(c for c in cells if c.id.endswith("tall_pitcher/target"))
    (target.path / "result.json").unlink()
    assert cli.main(args + ["--resume"]) == 0
    assert ran == [target.id]
    t1 = timings_of(out)
    assert set(t1["experiments"]) == {target.id}
    assert t1["total_s"] == pytest.approx(t1["experiments"][target.id] + COMPILE_S)
    assert t1["setup_s"] == COMPILE_S
    md = (out / "tables.md").read_text()
    assert f"Wall time {t1['total_s']:.1f} s = experiments" in md
    # Redraws and a resume with nothing left to run add no time.
    assert cli.main(args + ["--report-only"]) == 0
    assert cli.main(args + ["--report-only"]) == 0
    assert cli.main(args + ["--resume"]) == 0
    assert ran == [target.id]
    assert timings_of(out)["total_s"] == t1["total_s"]
    # A resume that runs another experiment adds its time and its new trial's compilation.
    rw = next(c for c in cells if c.id == "active/pitcher/random_walk")
    (rw.path / "result.json").unlink()
    assert cli.main(args + ["--resume"]) == 0
    t2 = timings_of(out)
    assert t2["experiments"][target.id] == t1["experiments"][target.id]
    assert t2["setup_s"] == 2 * COMPILE_S  # tall_pitcher's trial once, pitcher's once
    assert t2["total_s"] == pytest.approx(t1["total_s"] + t2["experiments"][rw.id] + COMPILE_S)
    assert t2["total_s"] == pytest.approx(t2["experiments_s"] + t2["setup_s"])


def test_account_time_keeps_the_first_compile_of_each_trial():
    timings = {"experiments": {"a": 1.0, "b": 2.0}, "compile_s": {"mujoco/pitcher": 3.0}}
    run.account_time(timings, {("pitcher", "mujoco"): 9.0, ("plate", "mujoco"): 0.5,
                               ("pitcher", "mjx"): 30.0}, "mujoco")
    assert timings["compile_s"]["mujoco/pitcher"] == 3.0  # a recompilation is not counted
    assert timings["setup_s"] == 3.5  # another backend's compile is not this run's setup
    assert timings["total_s"] == 6.5


# --------------------------------------------------------------------------------------------
# 3 and 4. Throughput of the run's backend only; an impossible ratio is a measurement error.


def _fake_measurements(monkeypatch, trials_per_s=80.0, rollout_trials_per_s=100.0):
    monkeypatch.setattr(run, "measure", lambda sim, seconds, seed: dict(
        batch=4, calls=3, trials=12, seconds=1.0, trials_per_s=trials_per_s))
    monkeypatch.setattr(run, "engine_limit", lambda sim, seconds, seed: dict(
        rollout_steps_per_s=rollout_trials_per_s * 500,
        rollout_trials_per_s=rollout_trials_per_s, steps_per_trial=500))


def test_throughput_measures_only_the_runs_backend(monkeypatch):
    """The default and paper profiles used to time MJX as well on a MuJoCo run (31 s of
    compiling); an older run's MJX entry is not this run's either."""
    _fake_measurements(monkeypatch)
    for name in ("default", "paper", "smoke"):
        profile = profiles.get_profile(name)
        sims = FakeSims("mujoco", profile.chains)
        timings = {"experiments": {"active/pitcher/random_walk": 10.0}}
        throughput = {"mjx": {"backend": "mjx", "available": True, "trials_per_s": 5.0}}
        run.run_throughput(profile, "mujoco", sims, timings, throughput, log=lambda *a: None)
        assert {b for _, b in sims.asked} == {"mujoco"}, name
        assert set(throughput) == {"mujoco"}, name
        assert throughput["mujoco"]["engine_ratio"] == pytest.approx(0.8)
        assert throughput["mujoco"]["engine_ratio_valid"] is True


def test_a_ratio_above_its_physical_limit_is_a_measurement_error(monkeypatch):
    _fake_measurements(monkeypatch, trials_per_s=117.0)
    throughput = {}
    run.run_throughput(profiles.get_profile("smoke"), "mujoco", FakeSims("mujoco", 2),
                       {"experiments": {}}, throughput, log=lambda *a: None)
    for markdown in (False, True):
        text = tables.render_throughput(throughput, markdown=markdown)
        assert "measurement error (noisy machine)" in text and "1.17" not in text
    rec = throughput["mujoco"]
    assert rec["engine_ratio"] == pytest.approx(1.17) and rec["engine_ratio_valid"] is False
    # Results saved without the flag are judged by the same limit; noise within it is shown.
    base = {"backend": "mujoco", "available": True, "object": "pitcher", "batch": 2}
    text = tables.render_throughput({"mujoco": dict(base, engine_ratio=1.17)}, markdown=True)
    assert "measurement error (noisy machine)" in text and "1.17" not in text
    text = tables.render_throughput({"mujoco": dict(base, engine_ratio=1.03)}, markdown=True)
    assert "1.03" in text and "measurement error" not in text


# --------------------------------------------------------------------------------------------
# 5. The robustness of each cell's grasps, measured apart from its learning.


def fake_robustness(calls):
    """Stands in for ``jg.learn.robustness``: the i-th distinct grasp held i mod (tries + 1)
    times; records the cells' objects (by their trial) and seeds."""
    def measure(result, *, trial, noise, seed, stop_early=False):
        g = select_grasps(result).grasps
        calls.append((result.object_name, seed))
        return Robustness(g, np.arange(len(g)) % (noise.tries + 1), noise)
    return measure


def test_cells_report_robustness_apart_from_their_learning(tmp_path, monkeypatch, capsys):
    profile, out, cells = saved_smoke_run(tmp_path)
    calls = []
    monkeypatch.setattr(run, "robustness", fake_robustness(calls))
    monkeypatch.setattr(run, "Simulators", FakeSims)
    monkeypatch.setattr(run, "run_cell", lambda *a, **k: pytest.fail("a saved cell re-learned"))
    args = ["--out", str(out), "--no-figures", "--no-throughput", "--quiet", "--jobs", "1"]
    # Not measured (the default): null in the JSON, no columns in the printed table.
    assert cli.main(["--profile", "smoke", "--backend", "mujoco", "--resume", *args]) == 0
    assert "robust share" not in capsys.readouterr().out and not calls
    res = json.loads((out / "results.json").read_text())
    before = res["tables"]
    cell0 = before["active"]["pitcher"]["random_walk"]
    assert cell0["robust_share"] is None and cell0["distinct_robust_new"] is None
    assert res["config"]["robust_tries"] == 0 and "robustness_s" not in res["timings"]
    # A results.json of schema version 2 (no robustness anywhere) resumes, measured now.
    for key in ("robust_tries", "pose_error"):
        del res["config"][key]
    res["schema_version"] = 2
    (out / "results.json").write_text(json.dumps(res))
    assert cli.main(["--resume", "--robust-tries", "4", "--pose-error", "2,1", *args]) == 0
    printed = capsys.readouterr().out
    assert sorted(calls) == sorted((c.obj, plan.cell_seed(0, c.row_id)) for c in cells)
    res = json.loads((out / "results.json").read_text())
    schema.validate(res)
    assert res["schema_version"] == schema.SCHEMA_VERSION == 3
    assert res["config"]["robust_tries"] == 4 and res["config"]["pose_error"] == [2.0, 1.0]
    for c in cells:
        saved = plan.load_saved(c)
        cell = (res["tables"]["active"][c.key[0]][c.key[1]] if c.table == "active" else
                res["tables"]["transfer"][c.key[0]][c.key[1]][c.key[2]])
        rob = saved.robustness
        assert rob.noise == PoseNoise(position_sd=0.002, angle_sd=1.0, tries=4)
        assert cell["robust_share"] == pytest.approx((rob.held >= 4).mean())
        assert cell["distinct_robust_new"] == saved.distinct_robust_new
        assert cell["robustness_trials"] == 4 * len(saved.grasps)
        old = (before["active"][c.key[0]][c.key[1]] if c.table == "active" else
               before["transfer"][c.key[0]][c.key[1]][c.key[2]])
        assert cell["per_run"] == old["per_run"]  # learning trials: not mixed with scoring
    assert set(res["timings"]["robustness"]) == {c.id for c in cells}
    t = res["timings"]
    assert t["experiments_s"] == 0.0 and t["total_s"] == t["setup_s"]  # scoring: apart
    assert "robust share" in printed and "distinct robust new" in printed
    trials = sum(4 * len(plan.load_saved(c).grasps) for c in cells)
    assert "under a pose error of 2 mm / 1°" in printed and f"took {trials} trials" in printed
    md = (out / "tables.md").read_text()
    assert "| robust share | distinct robust new |" in md
    # Resumed again (the saved profile's robust_tries): nothing is measured twice.
    n = len(calls)
    assert cli.main(["--resume", *args]) == 0
    assert len(calls) == n
    # Redrawn under another noise: those measurements are not this run's.
    assert cli.main(["--report-only", "--robust-tries", "5", *args]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["tables"]["active"]["pitcher"]["random_walk"]["robust_share"] is None


def test_unmeasured_cells_read_as_a_dash_beside_measured_ones():
    measured = dict(cell([3, 4]), robust_share=0.25, distinct_robust_new=2,
                    robustness_trials=40)
    tbl = {"active": {"pitcher": {"random_walk": cell([1, 2]),
                                  "kameleon_darting_biased": measured}}, "transfer": {}}
    rows = {r[0]: r for r in tables.learned_rows(tbl)}
    assert rows["pitcher/random_walk"][-2:] == ("—", "—")
    assert rows["pitcher/kameleon_darting_biased"][-2:] == ("25.0 %", "2")
    assert len(tables.learned_rows({"active": {"pitcher": {"random_walk": cell([1])}},
                                    "transfer": {}})[0]) == 5
    csv_rows = tables.rows_for_csv(tbl)
    assert {r["column"]: r["robust_share"] for r in csv_rows} == {
        "random_walk": "", "kameleon_darting_biased": 0.25}
