"""SHA-256 of a bench run's tables and claims without its timings: equal hashes mean equal
results (used to show a restructuring changed no behaviour).

    python -m jaxgrasp.bench --profile smoke --seed 0 --quiet --no-figures --no-throughput --out D
    python benchmarks/tables_hash.py D/results.json
"""

import hashlib
import json
import sys


def strip_timings(x):
    if isinstance(x, dict):
        return {k: strip_timings(v) for k, v in x.items()
                if not (k.endswith("_s") or "seconds" in k or k in ("wall", "timings"))}
    if isinstance(x, list):
        return [strip_timings(v) for v in x]
    return x


def main(path: str) -> str:
    d = json.load(open(path))
    blob = json.dumps(strip_timings({"tables": d["tables"], "comparison": d["comparison"]}),
                      sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()


if __name__ == "__main__":
    print(main(sys.argv[1]))
