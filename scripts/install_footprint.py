"""The time and size of a core-only install against the full one, each in a fresh venv.

    python scripts/install_footprint.py [--json FILE] [--keep-cache]

Two venvs are made in a temporary folder with the Python running this script:

* core: ``pip install -e .`` (numpy, numba, scipy, gymnasium, matplotlib);
* full: ``pip install torch==2.13.0`` then ``pip install -e ".[dev]"`` (README's install command;
  the torch pin installs the CPU wheel where pip's find-links has it, as on this project's machines).

For each it reports the wall time of the pip commands, the size of the venv's site-packages
(``du``-style: the sum of the files' sizes on disk) and the number of installed distributions
(``pip list``, pip and setuptools included in both counts).  Each venv gets an empty pip cache of
its own (in the temporary folder), so neither install reuses wheels the other downloaded or built
and the times are those of a first install; ``--keep-cache`` uses the user's cache instead.  The
time depends on where pip finds its wheels (a local index or PyPI) and on the machine's load,
so quote it with the machine; the sizes and counts do not.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

INSTALLS = {
    "core": [["-e", "."]],
    "full": [["torch==2.13.0"], ["-e", ".[dev]"]],
}


def _site_packages(venv: Path) -> Path:
    found = list(venv.glob("lib/python*/site-packages")) + list(venv.glob("Lib/site-packages"))
    if len(found) != 1:
        raise RuntimeError(f"expected one site-packages under {venv}, found {found}")
    return found[0]


def _disk_bytes(path: Path) -> int:
    # blocks actually allocated (du), not apparent sizes: what the install costs on disk
    total = 0
    for dirpath, _dirs, files in os.walk(path):
        for name in files:
            st = os.lstat(os.path.join(dirpath, name))
            total += st.st_blocks * 512
    return total


def measure(name: str, tmp: Path, keep_cache: bool) -> dict:
    venv = tmp / f"venv-{name}"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    env = dict(os.environ)
    if not keep_cache:
        env["PIP_CACHE_DIR"] = str(tmp / f"pip-cache-{name}")
    commands = []
    t0 = time.perf_counter()
    for args in INSTALLS[name]:
        cmd = [str(py), "-m", "pip", "install", "-q", *args]
        commands.append("pip install " + " ".join(args))
        subprocess.run(cmd, check=True, cwd=ROOT, env=env)
    seconds = time.perf_counter() - t0
    listed = json.loads(subprocess.run([str(py), "-m", "pip", "list", "--format=json"], check=True,
                                       capture_output=True, text=True, cwd=tmp).stdout)
    names = {d["name"].lower() for d in listed}
    return {
        "commands": commands,
        "seconds": round(seconds, 1),
        "site_packages_mb": round(_disk_bytes(_site_packages(venv)) / 1e6, 1),
        "packages": len(listed),
        "has_torch": "torch" in names,
        "has_stable_baselines3": "stable-baselines3" in names or "stable_baselines3" in names,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    p.add_argument("--keep-cache", action="store_true",
                   help="use the user's pip cache (default: an empty cache per venv, a first install)")
    args = p.parse_args(argv)
    pip_version = subprocess.run([sys.executable, "-m", "pip", "--version"], capture_output=True,
                                 text=True).stdout.split()[1:2]
    result: dict = {"python": platform.python_version(), "machine": platform.platform(),
                    "cpus": os.cpu_count(), "pip": pip_version[0] if pip_version else None,
                    "cache": "user's" if args.keep_cache else "empty, one per venv"}
    with tempfile.TemporaryDirectory(prefix="impact-env-footprint-") as d:
        for name in INSTALLS:
            print(f"{name}: installing ...", file=sys.stderr, flush=True)
            result[name] = measure(name, Path(d), args.keep_cache)
    core, full = result["core"], result["full"]
    print("| install | commands | time s | site-packages MB | packages |")
    print("|---|---|---|---|---|")
    for name in INSTALLS:
        r = result[name]
        print(f"| {name} | `{' && '.join(r['commands'])}` | {r['seconds']:.0f} | "
              f"{r['site_packages_mb']:.0f} | {r['packages']} |")
    print(f"\ncore/full: time {core['seconds'] / full['seconds']:.2f}, size "
          f"{core['site_packages_mb'] / full['site_packages_mb']:.3f}; Python {result['python']}, "
          f"{result['cpus']} CPUs, pip cache: {result['cache']}")
    # the core venv must really be core: otherwise the comparison says nothing
    if core["has_torch"] or core["has_stable_baselines3"]:
        print("error: the core install pulled torch or stable-baselines3", file=sys.stderr)
        return 1
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
