"""How similar each transfer object is to its active-set source, and whether the source's demos
hold on it unchanged (MuJoCo C): the measured basis of the paper's transfer story.

    python benchmarks/transfer_similarity.py --seed 0 --out bench_out/transfer_similarity.json

Writes the JSON and rewrites the table in ``assets/README.md`` (``--no-readme``: leave it).
"""

import argparse
import json
import re
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.objects import shipped

README = Path(__file__).resolve().parents[1] / "assets" / "README.md"
HEADER = ("| target | source | height | diameter | rim offset | wall | handle "
          "| source demos holding on target |")


def _pair(a, b) -> str:
    return f"{a:g} → {b:g}"


def table(rows) -> str:
    """The markdown table of ``rows`` (as written to ``assets/README.md``)."""
    lines = [HEADER, "|---|---|---|---|---:|---|---|---|"]
    for r in rows:
        held = r["source_demos_holding_on_target"]
        if held is None:
            cell = f"— (the {r['source']} has no demo)"
        else:
            cell = f"{held['success']} of {held['of']} ({' '.join(map(str, held['outcomes']))})"
        handle = " / ".join("yes" if h else "no" for h in r["handle"])
        lines.append(f"| {r['target']} | {r['source']} | {_pair(*r['height'])} | "
                     f"{_pair(*r['diameter'])} | {r['rim_offset']:+.3f} | {_pair(*r['wall'])} | "
                     f"{handle} | {cell} |")
    return "\n".join(lines) + "\n"


def write_readme(rows, path=README) -> None:
    """Replace the table that starts with ``HEADER`` in ``path``."""
    text = Path(path).read_text()
    pattern = re.compile(re.escape(HEADER) + r"\n(?:\|.*\n)*")
    if not pattern.search(text):
        raise ValueError(f"no transfer table in {path}")
    Path(path).write_text(pattern.sub(lambda _: table(rows), text, count=1))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="bench_out/transfer_similarity.json")
    p.add_argument("--no-readme", action="store_true", help="don't rewrite assets/README.md")
    args = p.parse_args()
    manifest = shipped.manifest()["objects"]
    demos = {}
    for source in jg.objects.names("active"):
        try:
            demos[source] = jg.learn.demonstrations(source, num=5, seed=args.seed).poses
        except ValueError as err:  # no grasp holds on this object
            print(f"{source}: no demos ({err})", flush=True)
            demos[source] = np.zeros((0, 7), np.float32)
    rows = []
    for target in jg.objects.names("transfer_a") + jg.objects.names("transfer_b"):
        source = jg.objects.similar(target)
        ds, dt = manifest[source]["dimensions"], manifest[target]["dimensions"]
        held = None
        if len(demos[source]):
            trial = jg.physics.make_trial(jg.physics.load_scene(target), backend="mujoco")
            outcome = np.asarray(trial(np.asarray(demos[source], np.float32)).outcome)
            held = {"success": int((outcome == 0).sum()), "of": len(outcome),
                    "outcomes": outcome.tolist()}
        row = {"target": target, "source": source,
               "height": [ds["height"], dt["height"]],
               "diameter": [ds["diameter"], dt["diameter"]],
               "rim_offset": round(0.5 * (dt["diameter"] - ds["diameter"]), 4),
               "wall": [ds["wall"], dt["wall"]],
               "handle": [manifest[source]["kind"] != "plate",  # pitchers and pans have one
                          manifest[target]["kind"] != "plate"],
               "source_demos_holding_on_target": held}
        rows.append(row)
        print(json.dumps(row), flush=True)
    with open(args.out, "w") as f:
        json.dump({"seed": args.seed, "pairs": rows}, f, indent=1)
    if not args.no_readme:
        write_readme(rows)


if __name__ == "__main__":
    main()
