"""The three ordinary changes of docs/architecture.md's recipes ("How to add an effect, a law, a
task option") made again, for real, from stored patches: what each change touches, counted
rather than claimed.

Each patch in ``scripts/recipe_trials/`` is one change as its recipe has it, written by hand
(the generated docs are not in it):

* ``effect.patch``: a second ADC on the force transducer (``effects.adc2``);
* ``law.patch``: pure velocity damping (the law ``damping``);
* ``option.patch``: a cost on the demanded force (the task option ``demand_weight``).

Per patch: a temporary ``git worktree`` of HEAD, the patch applied, ``python
scripts/docs_tables.py`` run (the recipes' "then"), the files that differ from HEAD counted
(by hand: the patch's; generated: the rest), and the checks run there: ``docs_tables.py
--check``, ``tests/test_recipes.py`` and ``tests/test_signal_path.py`` (no kernel compiles).
``--tests`` also runs the test files the recipe names (each compiles the kernels it reaches
afresh, as the patch changes the sources: minutes per change), ``--sphinx`` the docs' build
(``sphinx-build -W --keep-going``).

    python scripts/recipe_trial.py [--tests] [--sphinx] [--doc]
    python scripts/recipe_trial.py --render        # only rewrite the doc's block from the record

Writes ``docs/results/recipe_trials.json`` (per change: the files, each check's command, exit
status and seconds; command, versions, git, CPU, date); ``--doc`` also rewrites the
``recipe-trials`` block of docs/architecture.md from it.  ``tests/test_recipes.py`` checks that
every patch still applies to the tree (``git apply --check``) and touches only files its recipe
names.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PATCHES = ROOT / "scripts" / "recipe_trials"
RECORD = ROOT / "docs" / "results" / "recipe_trials.json"
DOC = ROOT / "docs" / "architecture.md"
BLOCK = "recipe-trials"

#: change: (its recipe's heading in docs/architecture.md, what it adds, the test files the recipe names)
TRIALS = {
    "effect": ("An effect", "a second ADC on the force transducer", ("tests/test_effects.py",)),
    "law": ("A classic law", "a velocity-damping law", ("tests/test_baselines.py",)),
    "option": ("A task option", "a cost on the demanded force", ("tests/test_env_options.py",)),
}
#: the checks every change gets (no kernel is compiled by them)
CHEAP = (("python", "scripts/docs_tables.py", "--check"),
         ("python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_recipes.py",
          "tests/test_signal_path.py"))
SPHINX = ("python", "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", "docs", "{tmp}/html")


def patch_of(change: str) -> Path:
    return PATCHES / f"{change}.patch"


def patch_files(patch: Path) -> list[str]:
    """The files ``patch`` changes or adds (``git apply --numstat``)."""
    out = subprocess.run(["git", "apply", "--numstat", str(patch)], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout
    return sorted(line.split("\t", 2)[2] for line in out.splitlines() if line.strip())


def _git(tree: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=tree, capture_output=True, text=True, check=True).stdout


def _changed(tree: Path) -> list[str]:
    """The files of ``tree`` that differ from its HEAD, new ones included."""
    _git(tree, "add", "-N", ".")
    return sorted(_git(tree, "diff", "--name-only", "HEAD").split())


def _check(tree: Path, command: tuple[str, ...], env: dict) -> dict:
    """Run ``command`` in ``tree`` ("python": this interpreter; "{tmp}": a scratch folder)."""
    argv = [sys.executable if a == "python" else a.replace("{tmp}", str(tree.parent)) for a in command]
    t0 = time.perf_counter()
    run = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True, check=False)
    out = {"command": " ".join(command).replace("{tmp}", "TMP"), "rc": run.returncode,
           "seconds": round(time.perf_counter() - t0, 1)}
    if run.returncode != 0:
        out["tail"] = (run.stdout + run.stderr)[-1500:]
    return out


def trial(change: str, tests: bool, sphinx: bool, cache: str) -> dict:
    """Apply ``change``'s patch to a fresh worktree of HEAD, regenerate the docs, count the files
    and run the checks."""
    heading, what, named = TRIALS[change]
    patch = patch_of(change)
    by_hand = patch_files(patch)
    with tempfile.TemporaryDirectory(prefix=f"recipe-{change}-") as tmp:
        tree = Path(tmp) / "tree"
        _git(ROOT, "worktree", "add", "--detach", str(tree), "HEAD")
        try:
            _git(tree, "apply", str(patch))
            env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": cache}
            regenerate = _check(tree, ("python", "scripts/docs_tables.py"), env)
            changed = _changed(tree)
            checks = [_check(tree, c, env) for c in CHEAP]
            if tests:
                checks.append(_check(tree, ("python", "-m", "pytest", "-q", "-p", "no:cacheprovider", *named),
                                     env))
            if sphinx:
                checks.append(_check(tree, SPHINX, env))
        finally:
            _git(ROOT, "worktree", "remove", "--force", str(tree))
    return {"recipe": heading, "adds": what, "patch": str(patch.relative_to(ROOT)), "by_hand": by_hand,
            "generated": [f for f in changed if f not in by_hand], "files": len(changed),
            "regenerate": regenerate, "checks": checks}


def block(record: dict) -> str:
    meta = record["meta"]
    lines = [f"Made again from the recipes (`{meta['command']}`, {meta['date'][:10]}, at commit "
             f"`{(meta['git']['commit'] or '?')[:10]}`): each change's patch (`scripts/recipe_trials/`) on a "
             "fresh worktree, then `python scripts/docs_tables.py`; the files that differ afterwards, and "
             "the checks run there.", "",
             "| change | files | written by hand | rewritten by docs_tables.py | checks passed |",
             "|---|---|---|---|---|"]
    for change, row in record["trials"].items():
        passed = [c for c in row["checks"] if c["rc"] == 0]
        names = ", ".join(_label(c["command"]) for c in row["checks"])
        lines.append(f"| {row['adds']} ({change}) | {row['files']} | "
                     f"{', '.join(f'`{f}`' for f in row['by_hand'])} | "
                     f"{', '.join(f'`{f}`' for f in row['generated']) or '-'} | "
                     f"{len(passed)} of {len(row['checks'])}: {names} |")
    return "\n".join(lines)


def _label(command: str) -> str:
    """A check's short name in the doc's table."""
    if "pytest" in command:
        return " ".join(f"`{a}`" for a in command.split() if a.startswith("tests/"))
    return "`docs_tables.py --check`" if "docs_tables" in command else "sphinx `-W`"


def write_doc(record: dict) -> None:
    from docs_tables import rewritten

    DOC.write_text(rewritten(DOC.read_text(), BLOCK, block(record)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tests", action="store_true",
                    help="also run the test files each recipe names (compiles)")
    ap.add_argument("--sphinx", action="store_true", help="also build the docs (sphinx-build -W)")
    ap.add_argument("--only", choices=sorted(TRIALS), action="append", help="only this change (repeatable)")
    ap.add_argument("--doc", action="store_true", help="rewrite docs/architecture.md's block")
    ap.add_argument("--render", action="store_true", help="only rewrite the block from the record")
    args = ap.parse_args(argv)
    if not args.render:
        from impact_env.eval.benchmark import run_meta

        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="recipe-trial-cache-") as cache:
            rows = {}
            for change in args.only or TRIALS:
                rows[change] = trial(change, args.tests, args.sphinx, cache)
                print(change, json.dumps({k: rows[change][k] for k in ("files", "by_hand", "generated")}),
                      [(c["command"], c["rc"]) for c in rows[change]["checks"]], file=sys.stderr, flush=True)
        record = {"trials": rows, "tests": args.tests, "sphinx": args.sphinx,
                  "meta": run_meta("python scripts/recipe_trial.py " + " ".join(argv if argv is not None
                                                                                else sys.argv[1:]),
                                   time.perf_counter() - t0, 0, 0.0)}
        RECORD.parent.mkdir(parents=True, exist_ok=True)
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
        failed = [(k, c["command"]) for k, row in rows.items() for c in [row["regenerate"], *row["checks"]]
                  if c["rc"] != 0]
    else:
        failed = []
    record = json.loads(RECORD.read_text())
    print(block(record))
    if args.doc or args.render:
        write_doc(record)
    if failed:
        print(f"failed: {failed}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
