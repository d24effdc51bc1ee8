#!/usr/bin/env bash
# Builds the wheel from this checkout, installs it (no deps: the venv's
# dependencies are reused) into a temporary target, and runs the built-in
# cells and a bundled scenario's loader from a temporary directory, so that
# nothing is found through the repository. Used by CI.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
py="$repo/.venv/bin/python"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"$py" -m pip wheel --no-deps -q -w "$tmp/dist" "$repo" >/dev/null 2>&1
"$py" -m pip install --no-deps -q --target "$tmp/site" "$tmp"/dist/*.whl
cd "$tmp"
export PYTHONPATH="$tmp/site"
"$py" - <<PYEOF
import drake_cfvol, pathlib
from drake_cfvol.comanip import diagrams_dir, load_scenario
from drake_cfvol.workcell import models_dir
where = pathlib.Path(drake_cfvol.__file__).resolve()
assert str(where).startswith("$tmp/site"), f"imported from {where}, not from the installed wheel"
assert str(models_dir()).startswith("$tmp/site"), models_dir()
print("wheel", drake_cfvol.__version__, "cells:", ", ".join(drake_cfvol.builtin_cells()),
      "| scenarios:", ", ".join(sorted(p.stem for p in diagrams_dir().glob("*.yaml"))))
load_scenario("automotive_push")
PYEOF
"$py" -m drake_cfvol plan automotive --path 1 --json
"$py" -m drake_cfvol plan aerospace --path 1 --json >/dev/null
# Uncertified: the wheel's data and recording are what is checked here;
# certification is the tests' (it would add about 2 minutes).
"$py" -m drake_cfvol simulate automotive_push --out run --json --scenario-text "{certify: false}" >/dev/null
test -s run/recording.html && test -s run/summary.json
echo "wheel check: OK"
