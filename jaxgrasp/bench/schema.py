"""JSON schema of ``results.json`` (other tools read it; the bench validates before writing)."""

import jsonschema

#: 2: claims carry p_value/alpha/test/verdict, and ``reproduced`` means "shown by the test";
#: timings define total_s = experiments_s + setup_s. 3: cells carry robust_share,
#: distinct_robust_new and robustness_trials (null: not measured), the config robust_tries
#: and pose_error, the timings robustness/robustness_s. Version 2 files read back as before.
SCHEMA_VERSION = 3

_COUNT = {"type": "number", "minimum": 0}
_OUTCOME_NUMS = {
    "type": "object",
    "required": ["success", "slipped", "collision", "miss"],
    "properties": {k: _COUNT for k in ("success", "slipped", "collision", "miss")},
}
_RUN = {
    "type": "object",
    "required": ["success", "slipped", "collision", "miss"],
    "properties": {k: {"type": "integer", "minimum": 0}
                   for k in ("success", "slipped", "collision", "miss")},
    "additionalProperties": False,
}
_NUM_OR_NULL = {"type": ["number", "null"]}

CELL = {
    "type": "object",
    "description": "Mean count per run of each outcome; a run is one chain of `proposals`.",
    "required": ["success", "slipped", "collision", "miss", "sd", "proposals", "runs",
                 "per_run"],
    "properties": {
        "success": _COUNT,
        "slipped": _COUNT,
        "collision": _COUNT,
        "miss": _COUNT,
        "sd": _OUTCOME_NUMS,
        "proposals": {"type": "integer", "minimum": 1},
        "runs": {"type": "integer", "minimum": 1},
        "per_run": {"type": "array", "minItems": 1, "items": _RUN},
        "acceptance_rate": _NUM_OR_NULL,
        "jump_rate": _NUM_OR_NULL,
        "learned_grasps": {"type": ["integer", "null"], "minimum": 0},
        "new_grasps": {"type": ["integer", "null"], "minimum": 0},
        "repeat_share": _NUM_OR_NULL,
        "robust_share": {"type": ["number", "null"], "minimum": 0, "maximum": 1,
                         "description": "share of the distinct successful grasps held in at "
                                        "least min_held of robust_tries tries under the "
                                        "pose error (null: not measured, or no grasp)"},
        "distinct_robust_new": {"type": ["integer", "null"], "minimum": 0},
        "robustness_trials": {"type": ["integer", "null"], "minimum": 0,
                              "description": "trials spent measuring robustness, apart from "
                                             "the learning trials in per_run"},
        "wall_s": _NUM_OR_NULL,
        "seed": {"type": "integer"},
        "source": {"type": "string"},
        "saved": {"type": "string"},
    },
}

ACTIVE_ROW = {
    "type": "object",
    "propertyNames": {"enum": ["random_walk", "kameleon_darting_random",
                               "kameleon_darting_biased"]},
    "additionalProperties": CELL,
}
TRANSFER_ROW = {
    "type": "object",
    "propertyNames": {"enum": ["source", "target"]},
    "additionalProperties": CELL,
}

THROUGHPUT = {
    "type": "object",
    "required": ["backend", "available"],
    "properties": {
        "backend": {"type": "string"},
        "available": {"type": "boolean"},
        "error": {"type": "string"},
        "object": {"type": "string"},
        "batch": {"type": "integer", "minimum": 1},
        "compile_s": _NUM_OR_NULL,
        "calls": {"type": "integer", "minimum": 0},
        "trials": {"type": "integer", "minimum": 0},
        "seconds": _NUM_OR_NULL,
        "trials_per_s": _NUM_OR_NULL,
        "chain_steps_per_s": _NUM_OR_NULL,
        "rollout_steps_per_s": _NUM_OR_NULL,
        "rollout_trials_per_s": _NUM_OR_NULL,
        "steps_per_trial": {"type": "integer", "minimum": 1},
        "engine_ratio": _NUM_OR_NULL,
        "engine_ratio_valid": {"type": "boolean",
                               "description": "false: engine_ratio exceeds its physical limit "
                                              "(1, plus a noise margin): a measurement error"},
        "source": {"type": "string"},
    },
}

SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "jaxgrasp bench results",
    "type": "object",
    "required": ["schema_version", "config", "versions", "device", "git", "timings", "tables",
                 "throughput", "comparison"],
    "properties": {
        "schema_version": {"const": SCHEMA_VERSION},
        "complete": {"type": "boolean"},
        "config": {
            "type": "object",
            "required": ["profile", "objects", "transfer_sets", "chains", "iterations",
                         "burn_in", "proposals", "backend", "seed"],
            "properties": {
                "profile": {"type": "string"},
                "objects": {"type": "array", "items": {"type": "string"}},
                "transfer_sets": {"type": "array", "items": {"type": "string"}},
                "chains": {"type": "integer", "minimum": 1},
                "iterations": {"type": "integer", "minimum": 1},
                "burn_in": {"type": "integer", "minimum": 0},
                "proposals": {"type": "integer", "minimum": 1},
                "backend": {"type": "string"},
                "seed": {"type": "integer"},
                "params": {"type": "object"},
                "robust_tries": {"type": "integer", "minimum": 0,
                                 "description": "0: robustness not measured"},
                "pose_error": {"type": "array", "minItems": 2, "maxItems": 2,
                               "items": {"type": "number", "minimum": 0},
                               "description": "position sd (mm), orientation sd (degrees)"},
            },
        },
        "versions": {"type": "object", "additionalProperties": {"type": ["string", "null"]}},
        "device": {"type": "object"},
        "git": {
            "type": "object",
            "required": ["revision"],
            "properties": {"revision": {"type": ["string", "null"]},
                           "dirty": {"type": ["boolean", "null"]}},
        },
        "timings": {
            "type": "object",
            "required": ["total_s", "experiments"],
            "properties": {
                "total_s": {"type": "number", "minimum": 0,
                            "description": "experiments_s + setup_s: the run's own work, each "
                                           "piece counted once however often it was resumed "
                                           "or redrawn"},
                "experiments_s": {"type": "number", "minimum": 0,
                                  "description": "sum of `experiments`"},
                "setup_s": {"type": "number", "minimum": 0,
                            "description": "compiling each object's trial on the run's "
                                           "backend, once (the first compilation recorded)"},
                "experiments": {"type": "object",
                                "additionalProperties": {"type": "number", "minimum": 0},
                                "description": "each experiment's own seconds, measured in "
                                               "the invocation that ran it"},
                "compile_s": {"type": "object",
                              "additionalProperties": {"type": "number", "minimum": 0}},
                "throughput_s": {"type": "number", "minimum": 0},
                "figures_s": {"type": "number", "minimum": 0},
                "robustness": {"type": "object",
                               "additionalProperties": {"type": "number", "minimum": 0},
                               "description": "each cell's seconds measuring the robustness "
                                            "of its grasps (not in total_s)"},
                "robustness_s": {"type": "number", "minimum": 0},
            },
        },
        "tables": {
            "type": "object",
            "required": ["active", "transfer"],
            "properties": {
                "active": {
                    "type": "object",
                    "propertyNames": {"enum": ["pitcher", "pan", "plate"]},
                    "additionalProperties": ACTIVE_ROW,
                },
                "transfer": {
                    "type": "object",
                    "propertyNames": {"enum": ["transfer_a", "transfer_b"]},
                    "additionalProperties": {"type": "object",
                                             "additionalProperties": TRANSFER_ROW},
                },
            },
        },
        "throughput": {"type": "object", "additionalProperties": THROUGHPUT},
        "comparison": {
            "type": "object",
            "required": ["claims"],
            "properties": {
                "claims": {
                    "type": "array",
                    "items": {
                        "type": "object",
                        "required": ["id", "text", "paper", "ours", "reproduced", "p_value",
                                     "alpha", "test", "verdict"],
                        "properties": {
                            "id": {"type": "string"},
                            "text": {"type": "string"},
                            "paper": {"type": ["boolean", "null"],
                                      "description": "the claim on the paper's numbers"},
                            "ours": {"type": ["boolean", "null"],
                                     "description": "the claim on this run's point estimates "
                                                    "(null: cells not run)"},
                            "reproduced": {"type": ["boolean", "null"],
                                           "description": "true only when `ours` agrees with "
                                                          "the paper and p_value < alpha"},
                            "p_value": {"type": ["number", "null"], "minimum": 0, "maximum": 1,
                                        "description": "this run's one-sided test of the claim "
                                                       "(null: not run, or untestable)"},
                            "alpha": {"type": "number", "exclusiveMinimum": 0,
                                      "exclusiveMaximum": 1},
                            "test": {"type": "string"},
                            "verdict": {"type": "string",
                                        "pattern": r"^(REPRODUCED \(p = [^)]+\)"
                                                   r"|not shown \(.+\)|not run)$"},
                            "paper_detail": {"type": "string"},
                            "ours_detail": {"type": "string"},
                        },
                    },
                },
            },
        },
        "figures": {"type": "array", "items": {"type": "string"}},
        "failures": {"type": "object", "additionalProperties": {"type": "string"}},
    },
}


def validate(results: dict) -> None:
    """Raise ``jsonschema.ValidationError`` if ``results`` does not match :data:`SCHEMA`,
    and ValueError if a run's counts do not sum to its cell's ``proposals`` or a claim is
    marked reproduced without its test passing (or the other way round)."""
    jsonschema.validate(results, SCHEMA)
    cells = [c for row in results["tables"]["active"].values() for c in row.values()]
    cells += [c for block in results["tables"]["transfer"].values() for row in block.values()
              for c in row.values()]
    for c in cells:
        for run in c["per_run"]:
            if sum(run.values()) != c["proposals"]:
                raise ValueError(f"a run's counts {run} do not sum to {c['proposals']}")
        if len(c["per_run"]) != c["runs"]:
            raise ValueError(f"cell has runs={c['runs']} but {len(c['per_run'])} per-run counts")
    for c in results["comparison"]["claims"]:
        # A claim is reproduced only where its test passes.
        shown = (c["ours"] is True and c["paper"] is True and c["p_value"] is not None
                 and c["p_value"] < c["alpha"])
        if (c["reproduced"] is None) != (c["ours"] is None) or (
                c["reproduced"] is not None and c["reproduced"] != shown):
            raise ValueError(f"claim {c['id']}: reproduced={c['reproduced']} but ours="
                             f"{c['ours']}, p = {c['p_value']}, alpha = {c['alpha']}")
        if bool(c["reproduced"]) != c["verdict"].startswith("REPRODUCED"):
            raise ValueError(f"claim {c['id']}: verdict {c['verdict']!r} disagrees with "
                             f"reproduced={c['reproduced']}")
