"""Write the leaderboard (docs/leaderboard.md) from the benchmark records kept in the repository.

Reads every record ``docs/results/benchmark/**/*.json`` (written by ``impact-env benchmark
--out docs/results/benchmark``; one per run, each with the suite's passive, reference and
oracle rows beside its policies), keeps the complete records of the suite (``--suite``,
default catch-v1), and replaces everything between the markers ``<!-- leaderboard:start -->``
and ``<!-- leaderboard:end -->`` of docs/leaderboard.md with a table: one row per policy, best
score first.  A policy in several records is taken from the first record (in path order) that
has it.  Nothing is run: the figures are the records'.

    python scripts/leaderboard.py            # rewrite docs/leaderboard.md
    python scripts/leaderboard.py --check    # fail (exit 1) if docs/leaderboard.md differs

The records themselves are made by one command (docs/benchmark.md, "Regenerating the
leaderboard")::

    impact-env benchmark thesis-ideal pd-penetration compiled:agents/models/best/best.policy.json \\
        compiled:agents/models/sac/sac.policy.json --out docs/results/benchmark
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "docs" / "results" / "benchmark"
PAGE = ROOT / "docs" / "leaderboard.md"
START, END = "<!-- leaderboard:start -->", "<!-- leaderboard:end -->"
SUITE_PAGE = ROOT / "docs" / "benchmark.md"  # its suite table, from impact_env.eval.suite
SUITE_START, SUITE_END = "<!-- suite-table:start -->", "<!-- suite-table:end -->"


def load_records(folder: Path, suite: str) -> list[tuple[Path, dict]]:
    """The complete records of ``suite`` under ``folder``, in path order."""
    out = []
    for path in sorted(folder.rglob("*.json")):
        try:
            record = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise SystemExit(f"{path}: not a JSON record ({exc})") from None
        if not isinstance(record, dict) or record.get("suite", {}).get("name") != suite:
            continue
        if not record.get("complete", False):
            raise SystemExit(f"{path}: a partial run (benchmark --drops): not a record for the leaderboard")
        out.append((path, record))
    return out


def _ci(value, pair, fmt="{:.1f}") -> str:
    def f(x):
        return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)
    if value is None:
        return "n/a"
    return f"{f(value)} [{f(pair[0])}, {f(pair[1])}]" if pair else f(value)


def _oracle_note(meta: dict) -> str:
    if meta.get("oracle_drops_searched"):
        return (f", of which {meta['oracle_search_s']:.0f} s searching the oracle on "
                f"{meta['oracle_drops_searched']} drops not yet cached")
    return ", the oracle replayed from its cache"


def _rank_key(st: dict) -> float:
    return -st["score"] if st.get("score") is not None else math.inf


def render(records: list[tuple[Path, dict]], root: Path = ROOT) -> str:
    """The generated block: the table and where its figures come from."""
    if not records:
        return "*No benchmark record yet: run the command in docs/benchmark.md.*"
    rows: dict[str, tuple[dict, dict, Path]] = {}
    for path, record in records:
        for spec, st in record["overall"].items():
            rows.setdefault(spec, (st, record, path))
    first = records[0][1]
    suite = first["suite"]
    set_names = [s["name"] for s in suite["sets"]]
    ref = suite["reference"]
    ranked = sorted(rows.items(), key=lambda kv: _rank_key(kv[1][0]))
    head = ["rank", "policy", "score* [95 % CI]", "score IQM [95 % CI]", f"P(better than {ref}) [95 % CI]",
            *(f"{n}: int E ms [95 % CI], x oracle" for n in set_names), "caught"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for rank, (spec, (st, record, _path)) in enumerate(ranked, start=1):
        per_set = []
        for name in set_names:
            pol = record["sets"].get(name, {}).get("policies", {}).get(spec)
            summary = pol["summary"] if pol is not None else {}
            cell = "n/a" if pol is None else _ci(summary.get("energy_integral_ms"),
                                                 summary.get("energy_integral_ms_ci95"), "{:.2f}")
            oracle = record["sets"].get(name, {}).get("policies", {}).get("oracle")
            mean = summary.get("energy_integral_ms")
            best = None if oracle is None else oracle["summary"].get("energy_integral_ms")
            if pol is not None and mean is not None and best:
                cell += f", {mean / best:.2f}x"
            per_set.append(cell)
        caught = st.get("caught_fraction")
        lines.append("| " + " | ".join([
            str(rank), f"`{spec}`", _ci(st.get("score"), st.get("score_ci95")),
            _ci(st.get("score_iqm"), st.get("score_iqm_ci95")),
            _ci(st.get("prob_improvement"), st.get("prob_improvement_ci95"), "{:.2f}"), *per_set,
            "n/a" if caught is None else f"{caught:.0%}"]) + " |")
    drops = ", ".join(f"{s['name']} {s['drops']} (seeds {s['seed']}-{s['seed'] + s['drops'] - 1})"
                      for s in suite["sets"])
    sources = []
    for path, record in records:
        meta = record["meta"]
        git = meta["git"]
        commit = (git.get("commit") or "unknown")[:12] + (" with changes" if git.get("dirty") else "")
        where = path.relative_to(root) if path.is_relative_to(root) else path
        # the CPU and the date stay in the record, not on the page
        sources.append(f"`{where}`: `{meta['command']}` (commit {commit}, "
                       f"impact_env {meta['versions'].get('impact_env')}, {meta['wall_time_s']:.0f} s"
                       + _oracle_note(meta) + ")")
    return "\n".join([
        f"*Written by `python scripts/leaderboard.py` from the records below; suite `{suite['name']}` "
        f"(version {suite['version']}), drops per set: {drops}.*", "",
        *lines, "",
        "\\* score: `100 (passive - policy) / (passive - oracle)` per drop on the energy integral, mean over "
        "every drop of the suite (0 = doing nothing, 100 = the per-drop oracle); intervals: 95 % stratified "
        f"bootstrap over the drops (the sets as strata); P(better than {ref}): the share of drops on which "
        "the policy's energy integral is lower than the reference's, ties half; x oracle: the set's mean "
        "energy integral over the oracle's.", "",
        "Records:", "", *(f"* {s}" for s in sources)])


def render_suite(name: str) -> str:
    """The suite's sets as a table (docs/benchmark.md), from its definition."""
    if str(ROOT) not in sys.path:  # this checkout's package, as the records were made with
        sys.path.insert(0, str(ROOT))
    from impact_env.eval.suite import get_suite

    lines = ["| set | scene | drops | seeds | what |", "|---|---|---|---|---|"]
    for ds in get_suite(name).sets:
        seeds = f"{ds.seed}-{ds.seed + ds.drops - 1}"
        lines.append(f"| `{ds.name}` | `{ds.scene}` | {ds.drops} | {seeds} | {ds.doc} |")
    return "\n".join(lines)


def between_markers(text: str, body: str, start: str = START, end: str = END) -> str:
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"a page lacks the markers {start} ... {end}")
    return pattern.sub(lambda _m: f"{start}\n{body}\n{end}", text, count=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="fail if the page differs from the records")
    ap.add_argument("--suite", default="catch-v1")
    ap.add_argument("--records", type=Path, default=RECORDS)
    ap.add_argument("--page", type=Path, default=PAGE)
    ap.add_argument("--suite-page", type=Path, default=SUITE_PAGE)
    args = ap.parse_args(argv)
    board = render(load_records(args.records, args.suite))
    pages = {args.page: between_markers(args.page.read_text(), board)}
    if args.suite_page.exists() and SUITE_START in args.suite_page.read_text():
        text = args.suite_page.read_text()
        pages[args.suite_page] = between_markers(text, render_suite(args.suite), SUITE_START, SUITE_END)
    stale = [p for p, new in pages.items() if p.read_text() != new]
    if args.check:
        for p in stale:
            print(f"{p} does not match the records in {args.records} and the suite's definition: run "
                  "python scripts/leaderboard.py", file=sys.stderr)
        return 1 if stale else 0
    for p in stale:
        p.write_text(pages[p])
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
