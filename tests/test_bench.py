"""python -m jaxgrasp.bench: tables, schema, claims, figures, and the smoke profile end to end.

Unit tests build LearnResult objects from random arrays (never shown by the real command);
the smoke test runs the real command once the learning workflows exist.
"""

import csv
import importlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxgrasp.bench import paper, plan, profiles, report, run, schema, tables
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos
from jaxgrasp.physics import TrialParams

OUT = paper.OUTCOMES


def fake_result(obj, method, chains, profile, seed, rng, sketch="biased", modes="demos"):
    """A LearnResult of random arrays with the shapes the workflows produce."""
    steps = profile.proposals
    params = plan.learn_params(profile)
    outcomes = rng.choice(4, size=(steps, chains), p=[0.1, 0.15, 0.45, 0.3]).astype(np.int8)
    pos = rng.normal(0.0, 0.05, size=(steps, chains, 7)).astype(np.float32)
    pos[..., 3] += 1.0
    acc = rng.random((steps, chains)) < 0.3
    return LearnResult(
        object_name=obj, object_hash="0" * 16, workflow="active", method=method,
        sketch=sketch, modes_kind=modes, seed=seed, backend="mujoco", params=params,
        positions=pos, proposals=pos + 0.01, outcomes=outcomes,
        epsilons=(rng.random((steps, chains)) * (outcomes == 0)).astype(np.float32),
        accepted=acc, is_jump=rng.random((steps, chains)) < 0.4,
        initial_positions=pos[0], modes=pos[0, :3].astype(float),
        sketch_points=pos[:, 0].astype(float), demos=Demos(pos[0, :3].astype(float), None),
        info={"physics": plan.physics_key()},
    )


def fabricate(profile, out, seed=0):
    """Save a fake result for every cell of ``profile`` under ``out``; return the plan."""
    rng = np.random.default_rng(seed)
    cells = plan.plan(profile, out)
    for c in cells:
        method = "random_walk" if c.column == "random_walk" else "kameleon_darting"
        fake_result(c.obj, method, profile.chains, profile,
                    plan.cell_seed(profile.seed, c.row_id), rng).save(c.path)
    return cells


def box_mesh(_name):
    import trimesh

    m = trimesh.creation.cylinder(radius=0.06, height=0.15)
    m.apply_translation([0, 0, 0.075])
    return m


@pytest.fixture(scope="module")
def small_profile():
    return profiles.get_profile("smoke").with_overrides(
        objects=("pitcher", "plate"), transfer_sets=("transfer_a", "transfer_b"), chains=3)


# --------------------------------------------------------------------------------------------


def test_make_cell_statistics_and_validation():
    counts = np.array([[1, 2, 3, 4], [3, 2, 1, 4]])
    cell = tables.make_cell(counts, 10)
    assert cell["success"] == 2.0 and cell["miss"] == 4.0
    assert cell["sd"]["success"] == pytest.approx(np.std([1, 3], ddof=1))
    assert cell["runs"] == 2 and len(cell["per_run"]) == 2
    assert sum(cell[o] for o in OUT) == cell["proposals"]
    with pytest.raises(ValueError, match="sum to proposals"):
        tables.make_cell(counts, 11)
    with pytest.raises(ValueError, match="shape"):
        tables.make_cell(np.ones((2, 3), int), 3)


def test_profiles_validate_and_map_objects():
    p = profiles.get_profile("default")
    assert p.proposals == p.burn_in + p.iterations
    assert profiles.get_profile("paper").proposals == 1100
    with pytest.raises(ValueError, match="unknown profile"):
        profiles.get_profile("huge")
    with pytest.raises(ValueError, match="objects"):
        profiles.Profile(name="x", objects=("mug",))
    with pytest.raises(ValueError, match="backend"):
        profiles.Profile(name="x", backend="bullet")
    assert profiles.parse_objects("soup_plate, pitcher") == ("pitcher", "plate")
    with pytest.raises(ValueError, match="unknown object"):
        profiles.parse_objects("teapot")
    smoke = profiles.get_profile("smoke")
    assert smoke.transfer_objects("transfer_a") == ("tall_pitcher",)


def test_plan_covers_every_cell_type_and_sources(tmp_path, small_profile):
    cells = plan.plan(small_profile, tmp_path)
    active = [c for c in cells if c.table == "active"]
    transfer = [c for c in cells if c.table == "transfer"]
    assert {c.column for c in active} == set(profiles.ACTIVE_METHODS)
    assert {c.column for c in transfer} == set(profiles.TRANSFER_MODES)
    assert {c.obj for c in transfer} == {"tall_pitcher", "soup_plate", "small_jug", "platter"}
    order = [c.id for c in cells]
    for c in transfer:
        assert c.source.column == profiles.TRANSFER_SOURCE_METHOD
        assert order.index(c.source.id) < order.index(c.id)
    # Seeds differ between rows (all cells of a row share the demos) and do not depend on
    # which other cells run.
    rows = {c.row_id for c in cells}
    assert len({plan.cell_seed(0, r) for r in rows}) == len(rows) == 2 + 4


def test_paper_claims_hold_on_paper_numbers_and_flip_when_data_flip():
    pub = paper.paper_tables()
    claims = paper.evaluate_claims(pub)
    assert all(c["paper"] is True for c in claims), [c for c in claims if not c["paper"]]
    assert all(c["ours"] is True for c in claims)
    # One run per cell: the point estimates agree, but only a claim whose test needs no
    # second chain (the sign test over runs) can be shown; the others are "not shown".
    for c in claims:
        if c["p_value"] is None:
            assert c["reproduced"] is False and c["verdict"].startswith("not shown (no test")
    assert {c["id"] for c in claims if c["reproduced"]} == {"misses_below_coll_slip"}
    # Swap random walk and Kameleon (random sketch): that claim must now fail.
    flipped = json.loads(json.dumps(pub))
    for row in flipped["active"].values():
        row["random_walk"], row["kameleon_darting_random"] = (
            row["kameleon_darting_random"], row["random_walk"])
    verdict = {c["id"]: c for c in paper.evaluate_claims(flipped)}
    assert verdict["kameleon_random_beats_rw"]["ours"] is False
    assert verdict["kameleon_random_beats_rw"]["reproduced"] is False
    # A run without transfer cells leaves transfer claims undecided, not "reproduced".
    only_active = {"active": pub["active"], "transfer": {}}
    verdict = {c["id"]: c for c in paper.evaluate_claims(only_active)}
    assert verdict["pitcher_transfer_fails"]["ours"] is None
    assert verdict["pitcher_transfer_fails"]["reproduced"] is None


def test_claims_carry_a_rank_test_over_chains():
    """With several runs per cell, a pairwise claim reports the one-sided Mann-Whitney p:
    small when one cell's chains all beat the other's, large when they are alike."""
    def cell(successes):
        runs = [dict(success=s, slipped=0, collision=0, miss=100 - s) for s in successes]
        return {"proposals": 100, "runs": len(runs), "per_run": runs,
                **{o: float(np.mean([r[o] for r in runs])) for o in OUT}}

    high, low = cell([30, 32, 35, 31, 33, 36, 34, 30]), cell([5, 7, 6, 4, 8, 5, 6, 7])
    assert paper._rank_p(high, low, "success") < 1e-3
    assert paper._rank_p(low, high, "success") > 0.99
    assert paper._rank_p(high, cell([30, 32, 35, 31, 33, 36, 34, 30]), "success") > 0.3
    assert paper._rank_p(high, cell([5]), "success") is None  # one run: no test
    tables = {"active": {"pan": {"kameleon_darting_random": high, "random_walk": low}}}
    verdict, detail, p = paper._compare_more(
        tables, [("pan", ("active", "pan", "kameleon_darting_random"),
                  ("active", "pan", "random_walk"))])
    assert verdict is True and "rank test p = " in detail and p < 1e-3


def test_paper_tables_sum_to_1100():
    pub = paper.paper_tables()
    cells = [c for r in pub["active"].values() for c in r.values()]
    cells += [c for b in pub["transfer"].values() for r in b.values() for c in r.values()]
    assert len(cells) == 9 + 12
    for c in cells:
        assert sum(c[o] for o in OUT) == 1100


def test_render_layout_contains_every_cell():
    pub = paper.paper_tables()
    text = tables.render_text("T2", *tables.active_grid(pub["active"]))
    lines = text.splitlines()
    assert lines[0] == "T2" and "Random walk" in lines[1] and "Succ." in lines[2]
    pitcher = next(line for line in lines if line.startswith("Pitcher"))
    assert pitcher.split() == ["Pitcher", "|", "0", "3", "433", "664", "|", "37", "48", "536",
                               "479", "|", "49", "80", "661", "310"]
    md = tables.render_markdown("T3", *tables.transfer_grid(pub["transfer"]))
    assert md.count("\n| tall_pitcher |") == 1 and "| 0 | 700 | 400 | 0 |" in md
    assert sum(line.startswith("| — |") for line in md.splitlines()) == 1  # block separator


def test_outputs_from_fabricated_results_validate(tmp_path, small_profile):
    out = tmp_path / "bench"
    cells = fabricate(small_profile, out)
    tbl, results = report.collect(cells, out, {}, small_profile, "mujoco")
    assert len(results) == len(cells)
    res = report.build_results(small_profile, "mujoco", tbl, {"total_s": 1.0, "experiments": {}},
                            {}, [], complete=True)
    report.write_outputs(out, res, small_profile)
    loaded = json.loads((out / "results.json").read_text())
    schema.validate(loaded)
    for o in small_profile.objects:
        assert set(loaded["tables"]["active"][o]) == set(profiles.ACTIVE_METHODS)
    assert set(loaded["tables"]["transfer"]["transfer_b"]["small_jug"]) == {"source", "target"}
    # Counts in the tables are those of the saved chains.
    c = next(c for c in cells if c.id == "active/plate/random_walk")
    saved = plan.load_saved(c)
    cell = loaded["tables"]["active"]["plate"]["random_walk"]
    assert cell["per_run"][1]["collision"] == int(saved.counts[1, 2])
    assert cell["runs"] == small_profile.chains
    with open(out / "tables.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(cells)
    for r in rows:
        assert sum(float(r[o]) for o in OUT) == pytest.approx(float(r["proposals"]))
    md = (out / "tables.md").read_text()
    assert "Table II" in md and "Table III" in md and "claims" in md
    # A corrupted count is caught by validation.
    bad = json.loads(json.dumps(loaded))
    bad["tables"]["active"]["plate"]["random_walk"]["per_run"][0]["miss"] += 1
    with pytest.raises(ValueError, match="sum"):
        schema.validate(bad)
    import jsonschema

    bad = json.loads(json.dumps(loaded))
    bad["tables"]["active"]["plate"]["gradient_descent"] = cell
    with pytest.raises(jsonschema.ValidationError):
        schema.validate(bad)


def test_figures_from_fabricated_results(tmp_path, small_profile):
    out = tmp_path / "bench"
    cells = fabricate(small_profile, out, seed=1)
    _, results = report.collect(cells, out, {}, small_profile, "mujoco")
    paths = report.make_figures(out, cells, results, small_profile, load_mesh=box_mesh)
    names = {p.split("/")[-1] for p in paths}
    assert {"fig5_grasps.png", "outcomes_active.png", "outcomes_transfer.png",
            "acceptance_active.png", "trace_transfer.png"} <= names
    assert len([p for p in paths if "/grasps/" in p]) == len(cells)
    for p in paths:
        assert (out / p).stat().st_size > 5000
    r = results[cells[0].id]
    eps = report.chain_epsilon(r)
    first = np.argmax(r.accepted[:, 0])
    assert np.isnan(eps[:first, 0]).all() and eps[first, 0] == r.epsilons[first, 0]


def test_cli_report_only_rebuilds_from_saved_results(tmp_path, small_profile, capsys):
    from jaxgrasp.bench import cli

    profile = profiles.get_profile("smoke")
    out = tmp_path / "bench"
    fabricate(profile, out)
    # A fresh --out with saved runs but no results.json: report-only needs no learning code.
    code = cli.main(["--profile", "smoke", "--out", str(out), "--report-only", "--no-figures",
                     "--quiet", "--backend", "mujoco"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "Table II" in printed and "Pitcher" in printed and "tall_pitcher" in printed
    res = json.loads((out / "results.json").read_text())
    schema.validate(res)
    assert res["complete"] is True
    # Without --resume an existing run is never overwritten.
    assert cli.main(["--profile", "smoke", "--out", str(out), "--quiet"]) == 2


def test_cli_report_only_and_resume_keep_the_saved_profile(tmp_path, monkeypatch):
    """Redrawing or resuming a run without --profile uses the profile it was made with: a
    smoke run redrawn as the default profile would report every cell "not run" and
    overwrite its results.json as incomplete; resumed, it would set its results aside."""
    from jaxgrasp.bench import cli

    profile = profiles.get_profile("smoke").with_overrides(seed=3)
    out = tmp_path / "bench"
    fabricate(profile, out)
    assert cli.main(["--profile", "smoke", "--seed", "3", "--out", str(out), "--report-only",
                     "--no-figures", "--quiet", "--backend", "mujoco"]) == 0
    assert cli.main(["--out", str(out), "--report-only", "--no-figures", "--quiet"]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["config"]["profile"] == "smoke" and res["config"]["seed"] == 3
    assert res["complete"] is True

    def must_not_run(*a, **k):
        raise AssertionError("a saved, matching experiment was run again")

    monkeypatch.setattr(run, "run_cell", must_not_run)
    assert cli.main(["--out", str(out), "--resume", "--no-figures", "--no-throughput",
                     "--quiet", "--jobs", "1"]) == 0
    assert not (out / "runs" / ".stale").exists()
    # Flags still override the saved profile; a fresh --out starts from the default profile.
    args = cli.parse_args(["--out", str(out), "--report-only", "--chains", "5"])
    assert cli._base_profile(args).chains == profile.chains
    assert cli._base_profile(cli.parse_args(["--out", str(tmp_path / "new")])).name == "default"


# --------------------------------------------------------------------------------------------
# The real command (needs the learning workflows, physics and objects).


def _workflows_available():
    try:
        learn = importlib.import_module("jaxgrasp.learn")
        importlib.import_module("jaxgrasp.objects").load  # noqa: B018
    except (ImportError, AttributeError):
        return False
    return hasattr(learn, "active") and hasattr(learn, "transfer")


@pytest.mark.slow  # ~2 min on an idle 2-core machine: `make test-all` (CI keeps the CLI tests)
@pytest.mark.skipif(not _workflows_available(), reason="jg.learn.active/transfer not built yet")
def test_smoke_profile_end_to_end(tmp_path, repo_root):
    out = tmp_path / "smoke"
    # Share the suite's persistent compile cache (conftest sets it for this process only).
    env = dict(os.environ)
    env.setdefault("JAXGRASP_CACHE_DIR", str(repo_root / ".cache" / "jax"))
    proc = subprocess.run(
        [sys.executable, "-m", "jaxgrasp.bench", "--profile", "smoke", "--out", str(out),
         "--quiet"],
        cwd=repo_root, capture_output=True, text=True, timeout=900, env=env,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    for f in ("results.json", "results.schema.json", "tables.md", "tables.csv",
              "figures/fig5_grasps.png", "figures/outcomes_active.png",
              "figures/acceptance_transfer.png"):
        assert (out / f).is_file(), f
    res = json.loads((out / "results.json").read_text())
    schema.validate(res)
    smoke = profiles.get_profile("smoke")
    assert res["complete"] is True
    active = res["tables"]["active"]
    transfer = res["tables"]["transfer"]
    assert set(active) == set(smoke.objects)
    cells = [c for r in active.values() for c in r.values()]
    cells += [c for b in transfer.values() for r in b.values() for c in r.values()]
    assert len(cells) == len(smoke.objects) * 3 + 2 * len(smoke.objects) * len(
        smoke.transfer_sets)
    for c in cells:
        assert c["proposals"] == smoke.proposals and c["runs"] == smoke.chains
        assert sum(c[o] for o in OUT) == pytest.approx(smoke.proposals)
        for r in c["per_run"]:
            assert sum(r.values()) == smoke.proposals
    assert any(t["available"] for t in res["throughput"].values())
    c = res["throughput"].get("mujoco", {})
    if c.get("available"):  # the C trial's speed next to the engine's own rollout speed
        assert c["steps_per_trial"] == TrialParams().num_steps
        assert c["rollout_steps_per_s"] > 0 and c["engine_ratio"] > 0
    assert "Table II" in proc.stdout and "claims" in proc.stdout
    # Demonstrations are computed once per row (object, seed) and saved for reuse.
    demo_files = sorted((out / "runs" / "demos").glob("*/*.npz"))
    rows_with_demos = len(smoke.objects) * (1 + len(smoke.transfer_sets))
    assert len(demo_files) == rows_with_demos, demo_files


def test_cli_resume_reuses_matching_saved_experiments(tmp_path, monkeypatch):
    from jaxgrasp.bench import cli

    profile = profiles.get_profile("smoke")
    out = tmp_path / "bench"
    cells = fabricate(profile, out)

    def must_not_run(*a, **k):
        raise AssertionError("a saved, matching experiment was run again")

    monkeypatch.setattr(run, "run_cell", must_not_run)
    # --jobs 1: run_cell runs in this process, where the test replaces it.
    code = cli.main(["--profile", "smoke", "--out", str(out), "--resume", "--no-figures",
                     "--no-throughput", "--quiet", "--backend", "mujoco", "--jobs", "1"])
    assert code == 0
    res = json.loads((out / "results.json").read_text())
    assert res["complete"] is True and not res["failures"]
    # Another seed is another experiment: resume must not pass the old results off as it.
    calls = []

    def record(cell, *a, **k):
        calls.append(cell.id)
        raise ValueError("no demonstrated grasp (test)")

    monkeypatch.setattr(run, "run_cell", record)
    code = cli.main(["--profile", "smoke", "--out", str(out), "--resume", "--no-figures",
                     "--no-throughput", "--quiet", "--backend", "mujoco", "--seed", "7",
                     "--jobs", "1"])
    assert code == 1
    # The first active failure skips the rest of its row; transfers skip their failed source.
    assert calls == [cells[0].id]
    res = json.loads((out / "results.json").read_text())
    assert set(res["failures"]) == {c.id for c in cells} and res["complete"] is False
    assert not res["tables"]["active"] and not res["tables"]["transfer"]
    # The old results were set aside, not deleted.
    assert len(list((out / "runs" / ".stale").rglob("result.json"))) == len(cells)


def test_resume_does_not_reuse_results_of_other_physics(tmp_path, small_profile):
    out = tmp_path / "bench"
    cells = fabricate(small_profile, out)
    c = cells[0]
    saved = plan.load_saved(c)
    assert plan.matches(saved, c, small_profile, "mujoco")
    saved.info["physics"] = "(GripperParams(finger_damping=30.0), TrialParams())"
    assert not plan.matches(saved, c, small_profile, "mujoco")
    saved.info.pop("physics")  # saved before results recorded their physics
    assert not plan.matches(saved, c, small_profile, "mujoco")
