"""Table cells from per-run outcome counts, and Tables II/III as text, Markdown and CSV.

A *cell* is one (object, method) or (transfer set, object, modes) entry of the paper's tables:
``runs`` independent chains, each one run of ``proposals`` proposals whose outcomes are
counted. Cells are plain dicts (they go straight into ``results.json``).
"""

import csv
import io

import numpy as np

from jaxgrasp.bench.paper import (
    ALPHA,
    OUTCOMES,
    PAPER_PROPOSALS,
    TABLE_II,
    TABLE_III,
    paper_tables,
)
from jaxgrasp.bench.profiles import ACTIVE_METHODS, TRANSFER_MODES, TRANSFER_SETS
from jaxgrasp.bench.throughput import engine_ratio_valid

HEADS = ("Succ.", "Slip.", "Coll.", "Miss")
METHOD_TITLES = {
    "random_walk": "Random walk",
    "kameleon_darting_random": "Kameleon+GDMC, random init.",
    "kameleon_darting_biased": "Kameleon+GDMC, biased init.",
}
MODES_TITLES = {"source": "Modes of a similar object", "target": "Modes of the actual object"}
SET_TITLES = {"transfer_a": "top row of Fig. 3", "transfer_b": "bottom row of Fig. 3"}


def make_cell(counts, proposals: int, **extra) -> dict:
    """A table cell from per-run counts.

    Parameters
    ----------
    counts : (runs, 4) int array-like
        success / slipped / collision / miss counts of each run (chain).
    proposals : int
        Proposals per run; every row of ``counts`` must sum to it.
    **extra
        Further JSON-able fields stored in the cell (acceptance rate, wall time, ...).

    Returns
    -------
    dict with the mean count per run of each outcome, ``sd`` (sample standard deviation
    across runs, 0 for one run), ``proposals``, ``runs`` and ``per_run``.
    """
    c = np.asarray(counts)
    if c.ndim != 2 or c.shape[1] != 4 or c.shape[0] < 1:
        raise ValueError(f"counts must have shape (runs, 4), got {c.shape}")
    if not np.issubdtype(c.dtype, np.integer):
        if not np.all(c == np.round(c)):
            raise ValueError("counts must be integers")
        c = c.astype(np.int64)
    sums = c.sum(axis=1)
    if np.any(sums != proposals):
        raise ValueError(
            f"every run's counts must sum to proposals={proposals}, got row sums {sums.tolist()}"
        )
    mean = c.mean(axis=0)
    sd = c.std(axis=0, ddof=1) if c.shape[0] > 1 else np.zeros(4)
    cell = {k: float(v) for k, v in zip(OUTCOMES, mean, strict=True)}
    cell["sd"] = {k: float(v) for k, v in zip(OUTCOMES, sd, strict=True)}
    cell["proposals"] = int(proposals)
    cell["runs"] = int(c.shape[0])
    cell["per_run"] = [{k: int(v) for k, v in zip(OUTCOMES, row, strict=True)} for row in c]
    cell.update(extra)
    return cell


def fmt(cell: dict, outcome: str) -> str:
    """``mean±sd`` (integers for a single run, like the paper)."""
    m = cell[outcome]
    if cell["runs"] == 1:
        return f"{m:.0f}"
    digits = 0 if m >= 100 else 1
    return f"{m:.{digits}f}±{cell['sd'][outcome]:.{digits}f}"


def _cells(row: dict, keys) -> list:
    out = []
    for k in keys:
        c = row.get(k)
        out.extend([fmt(c, o) for o in OUTCOMES] if c else ["-"] * 4)
    return out


def active_grid(active: dict) -> tuple:
    """(groups, rows) of Table II: groups [(title, 4 heads)], rows [(label, values)]."""
    methods = [m for m in ACTIVE_METHODS if any(m in r for r in active.values())]
    groups = [(METHOD_TITLES[m], HEADS) for m in methods]
    rows = [(o.capitalize(), _cells(active[o], methods)) for o in TABLE_II if o in active]
    return groups, [rows]


def transfer_grid(transfer: dict) -> tuple:
    """(groups, blocks) of Table III: one block of rows per transfer set."""
    modes = [m for m in TRANSFER_MODES if any(m in r for b in transfer.values() for r in
                                              b.values())]
    groups = [(MODES_TITLES[m], HEADS) for m in modes]
    blocks = []
    for s in TRANSFER_SETS:
        if s not in transfer:
            continue
        rows = [(o, _cells(transfer[s][o], modes)) for o in TABLE_III[s] if o in transfer[s]]
        blocks.append(rows)
    return groups, blocks


def render_text(title: str, groups, blocks) -> str:
    """A plain-text table with the paper's two header rows and ``|`` between groups."""
    label_w = max([len(r[0]) for b in blocks for r in b] + [6])
    ncol = 4 * len(groups)
    widths = [len(h) for _, heads in groups for h in heads]
    for b in blocks:
        for _, vals in b:
            widths = [max(w, len(v)) for w, v in zip(widths, vals, strict=True)]
    group_w = [sum(widths[4 * g:4 * g + 4]) + 2 * 3 for g in range(len(groups))]
    # A group title wider than its columns widens the last column of the group.
    for g, (t, _) in enumerate(groups):
        if len(t) > group_w[g]:
            widths[4 * g + 3] += len(t) - group_w[g]
            group_w[g] = len(t)

    def line(label, vals):
        parts = []
        for g in range(len(groups)):
            parts.append("  ".join(v.rjust(widths[4 * g + j]) for j, v in
                                   enumerate(vals[4 * g:4 * g + 4])))
        return label.ljust(label_w) + " | " + " | ".join(parts)

    head1 = " " * label_w + " | " + " | ".join(t.center(group_w[g]) for g, (t, _) in
                                               enumerate(groups))
    head2 = line("", [h for _, hs in groups for h in hs])
    rule = "-" * len(head2)
    out = [title, head1, head2, rule]
    for i, b in enumerate(blocks):
        if i:
            out.append(rule)
        out.extend(line(lab, vals) for lab, vals in b)
    assert ncol == len(widths)
    return "\n".join(out)


def render_markdown(title: str, groups, blocks) -> str:
    """A Markdown table: group titles on the header row, the outcome heads as a bold row."""
    ncol = 4 * len(groups)
    head = ["Object"] + [t if j == 0 else "" for t, _ in groups for j in range(4)]
    sub = [""] + [f"**{h}**" for _, hs in groups for h in hs]
    out = [f"**{title}**", "", "| " + " | ".join(head) + " |",
           "|" + "---|" + "---:|" * ncol, "| " + " | ".join(sub) + " |"]
    for i, b in enumerate(blocks):
        if i:
            out.append("| " + " | ".join(["—"] * (ncol + 1)) + " |")
        out.extend("| " + " | ".join([lab] + vals) + " |" for lab, vals in b)
    return "\n".join(out)


def table_titles(proposals: int, runs: int) -> tuple:
    unit = f"counts per run of {proposals} proposals" + (
        f", mean±sd over {runs} chains" if runs > 1 else ""
    )
    return (
        f"Table II: active learning ({unit})",
        f"Table III: transfer learning ({unit}; blocks: transfer_a, transfer_b)",
    )


def rows_for_csv(tables: dict, paper: dict | None = None) -> list:
    """One flat row per cell (long format), with the paper's counts beside ours."""
    rows = []

    def add(table, tset, obj, col, cell, pcell):
        r = dict(table=table, transfer_set=tset, object=obj, column=col,
                 runs=cell["runs"], proposals=cell["proposals"])
        for o in OUTCOMES:
            r[o] = cell[o]
        for o in OUTCOMES:
            r[f"{o}_sd"] = cell["sd"][o]
        for k in ("acceptance_rate", "jump_rate", "learned_grasps", "new_grasps", "repeat_share",
                  "robust_share", "distinct_robust_new", "robustness_trials", "wall_s"):
            value = cell.get(k, "")
            r[k] = "" if value is None else value
        r["paper_proposals"] = pcell["proposals"] if pcell else ""
        for o in OUTCOMES:
            r[f"paper_{o}"] = int(pcell[o]) if pcell else ""
        rows.append(r)

    p_act = (paper or {}).get("active", {})
    p_tr = (paper or {}).get("transfer", {})
    for o, row in tables.get("active", {}).items():
        for m, cell in row.items():
            add("II", "", o, m, cell, p_act.get(o, {}).get(m))
    for s, block in tables.get("transfer", {}).items():
        for o, row in block.items():
            for m, cell in row.items():
                add("III", s, o, m, cell, p_tr.get(s, {}).get(o, {}).get(m))
    return rows


def to_csv(rows: list) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return buf.getvalue()


def _verdict(c: dict) -> str:
    """The claim's verdict with its p-value (results written before verdicts had one: from
    ``reproduced`` alone, flagged as untested)."""
    if "verdict" in c:
        return c["verdict"]
    return {True: "REPRODUCED (untested)", False: "NOT reproduced", None: "not run"}[
        c["reproduced"]]


def render_claims_text(claims: list) -> str:
    """The comparison with the paper's qualitative claims, one line per claim."""
    word = {True: "yes", False: "no", None: "n/a"}
    lines = ["Paper's claims (paper verdict on its numbers / this run's point estimates; "
             "REPRODUCED only where this run's one-sided test passes at "
             f"alpha = {ALPHA:g}):"]
    for c in claims:
        lines.append(f"  [{_verdict(c)}] {c['text']} — paper: {word[c['paper']]}, "
                     f"ours (point estimates): {word[c['ours']]}")
        lines.append(f"      ours: {c['ours_detail']}")
    return "\n".join(lines)


def render_claims_markdown(claims: list) -> str:
    word = {True: "yes", False: "no", None: "n/a"}
    out = ["| Claim | Paper | This run (point estimates) | Verdict (one-sided test, "
           f"α = {ALPHA:g}) | Run details |", "|---|---|---|---|---|"]
    for c in claims:
        v = _verdict(c)
        mark = "✅ " if c["reproduced"] else ""
        out.append(f"| {c['text']} | {word[c['paper']]} | {word[c['ours']]} | {mark}{v} | "
                   f"{c['ours_detail']} |")
    return "\n".join(out)


def _measured(tbl: dict) -> bool:
    """Whether any cell's grasps were tried under the pose error."""
    return any(c.get("robustness_trials") is not None for _, c in _learned_cells(tbl))


def _learned_cells(tbl: dict) -> list:
    rows = []
    for o, row in tbl.get("active", {}).items():
        for m, c in row.items():
            rows.append((f"{o}/{m}", c))
    for s, block in tbl.get("transfer", {}).items():
        for o, row in block.items():
            for m, c in row.items():
                rows.append((f"{s}/{o}/{m}", c))
    return rows


def learned_rows(tbl: dict) -> list:
    """(cell, successes over all chains, distinct successful grasps, distinct new grasps,
    repeat share[, robust share, distinct robust new]) rows (docs/design.md: 1 cm / 10°, the
    gripper's 180° symmetry): success counts include re-proposals of the same grasps, the
    distinct columns do not. The robustness columns only when some cell was measured ("—"
    for a cell that was not)."""
    measured = _measured(tbl)
    out = []
    for label, c in _learned_cells(tbl):
        total = sum(r["success"] for r in c["per_run"])
        share = c.get("repeat_share")
        row = (label, str(total), str(c.get("learned_grasps", "-")),
               str(c.get("new_grasps", "-")), "-" if share is None else f"{share:.2f}")
        if measured:
            robust, new = c.get("robust_share"), c.get("distinct_robust_new")
            row += ("—" if robust is None else f"{100 * robust:.1f} %",
                    "—" if new is None else str(new))
        out.append(row)
    return out


def render_plain(head: tuple, rows: list, *, markdown: bool, right: tuple = ()) -> str:
    """A one-header table of strings as Markdown or aligned text; ``right``: the indices of
    right-aligned (numeric) columns."""
    if markdown:
        rule = "|" + "".join("---:|" if i in right else "---|" for i in range(len(head)))
        lines = ["| " + " | ".join(head) + " |", rule]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])
    w = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    return "\n".join("  ".join(str(x).rjust(n) if i in right else str(x).ljust(n) for i, (x, n)
                                in enumerate(zip(r, w, strict=True))) for r in [head, *rows])


def render_learned(tbl: dict, *, markdown: bool) -> str:
    head = ("cell", "successes", "distinct", "distinct new", "repeat share")
    if _measured(tbl):
        head += ("robust share", "distinct robust new")
    return render_plain(head, learned_rows(tbl), markdown=markdown,
                        right=tuple(range(1, len(head))))


def robustness_note(tbl: dict, profile) -> str:
    """What the robustness columns mean and the trials they cost (kept out of the tables'
    proposals); empty when no cell was measured."""
    noise = profile.noise
    if noise is None or not _measured(tbl):
        return ""
    trials = sum(c.get("robustness_trials") or 0 for _, c in _learned_cells(tbl))
    return (f"Robust share: the share of a cell's distinct successful grasps that held in at "
            f"least {noise.min_held} of {noise.tries} tries under a pose error of {noise.label} "
            f"(jg.learn.robustness, on the cell's own trial); distinct robust new: those that "
            f"are also new. Measuring them took {trials} trials, not counted in the tables.")


def render_tables(tbl: dict, profile, *, markdown: bool) -> str:
    """Both tables (this run, then the paper's) as text or Markdown; ``profile``: the run's
    :class:`~jaxgrasp.bench.profiles.Profile` (proposals and chains in the titles)."""
    render = render_markdown if markdown else render_text
    t2, t3 = table_titles(profile.proposals, profile.chains)
    pub = paper_tables()
    parts = []
    if tbl["active"]:
        parts.append(render(t2, *active_grid(tbl["active"])))
    if tbl["transfer"]:
        parts.append(render(t3, *transfer_grid(tbl["transfer"])))
    p2, p3 = table_titles(PAPER_PROPOSALS, 1)
    parts.append(render("Paper " + p2, *active_grid(pub["active"])))
    parts.append(render("Paper " + p3, *transfer_grid(pub["transfer"])))
    return "\n\n".join(parts)


def render_throughput(throughput: dict, *, markdown: bool) -> str:
    """Speed per measured backend; a full ÷ rollout-alone ratio above its physical limit
    (:data:`~jaxgrasp.bench.throughput.MAX_ENGINE_RATIO`) is shown as a measurement error."""
    head = ("backend", "object", "batch", "compile s", "trials/s", "chain steps/s",
            "÷ rollout alone")

    def f(x, d=1):
        return "-" if x is None else f"{x:.{d}f}"

    rows = []
    for b, t in throughput.items():
        if not t.get("available"):
            rows.append((b, "-", "-", "-", f"unavailable: {t.get('error', '')}"[:60], "-", "-"))
            continue
        ratio = t.get("engine_ratio")
        valid = t.get("engine_ratio_valid", engine_ratio_valid(ratio))
        rows.append((b, t.get("object", "-"), str(t.get("batch", "-")), f(t.get("compile_s")),
                     f(t.get("trials_per_s")), f(t.get("chain_steps_per_s")),
                     f(ratio, 2) if valid else "measurement error (noisy machine)"))
    return render_plain(head, rows, markdown=markdown)
