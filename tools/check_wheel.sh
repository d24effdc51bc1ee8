#!/usr/bin/env bash
# The installed wheel, as a user gets it: builds the wheel from this
# checkout, installs it with its dependencies into a fresh virtual
# environment (not editable), and from a folder outside the checkout imports
# every module of the package, then runs `cfvol --help`, `cfvol plan` and a
# short uncertified `cfvol simulate`. Used by CI (.ci/run).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
PY=${PYTHON:-python3}
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"$PY" -m venv "$tmp/venv"
py="$tmp/venv/bin/python"
# pip's and setuptools' chatter goes to a log, shown only if a step fails.
log="$tmp/pip.log"
# Built from a copy of the checkout's files (tracked, and new ones git does
# not ignore): a build/ folder left by an earlier build would otherwise
# slip its stale modules into the wheel.
src="$tmp/src"
mkdir "$src"
if git -C "$repo" rev-parse --git-dir >/dev/null 2>&1; then
  (cd "$repo" && git ls-files -co --exclude-standard -z |
     while IFS= read -r -d '' f; do if [ -e "$f" ]; then cp --parents "$f" "$src"; fi; done)
else
  cp -r "$repo/." "$src"
fi
if ! { "$py" -m pip install -q --upgrade pip && "$py" -m pip wheel --no-deps -q -w "$tmp/dist" "$src" &&
       "$py" -m pip install -q "$tmp"/dist/*.whl; } >"$log" 2>&1; then
  cat "$log" >&2
  echo "check_wheel.sh: error: building or installing the wheel failed (log above)" >&2
  exit 1
fi
mkdir "$tmp/work"
cd "$tmp/work"
"$py" - <<PYEOF
import importlib, pathlib, pkgutil
import drake_cfvol
from drake_cfvol.comanip import diagrams_dir, load_scenario
from drake_cfvol.scene.workcell import models_dir
site = pathlib.Path("$tmp/venv")
where = pathlib.Path(drake_cfvol.__file__).resolve()
assert site in where.parents, f"imported from {where}, not from the installed wheel"
assert site in pathlib.Path(models_dir()).resolve().parents, models_dir()
# Every module of the package (__main__ is the command line itself, run below).
root = pathlib.Path(drake_cfvol.__file__).parent
names = [m.name for m in pkgutil.walk_packages([str(root)], "drake_cfvol.")
         if m.name != "drake_cfvol.__main__"]
on_disk = {".".join(p.relative_to(root.parent).with_suffix("").parts).removesuffix(".__init__")
           for p in root.rglob("*.py") if p.stem != "__main__"}
missing = sorted(on_disk - set(names) - {"drake_cfvol"})
assert not missing, f"modules on disk that the walk did not find: {missing}"
for name in names:
    importlib.import_module(name)
print("wheel", drake_cfvol.__version__, f"imports all {len(names)} modules | cells:",
      ", ".join(drake_cfvol.builtin_cells()), "| scenarios:",
      ", ".join(sorted(p.stem for p in diagrams_dir().glob("*.yaml"))))
load_scenario("automotive_push")
PYEOF
cfvol="$tmp/venv/bin/cfvol"
"$cfvol" --help >/dev/null
"$py" -m drake_cfvol --help >/dev/null
"$cfvol" plan automotive --path 1 --json
"$cfvol" plan aerospace --path 1 --json >/dev/null
# Uncertified: the wheel's data and recording are what is checked here;
# certification is the tests'.
"$cfvol" simulate automotive_push --out run --json --scenario-text "{bounds: {certify: null}}" >/dev/null
test -s run/recording.html && test -s run/summary.json
# Bad input refused from the wheel too (issue 49): exit 2 and one line, no
# traceback, nothing overwritten.
refused() {  # refused <what> <command...>: exit 2 with one "cfvol: error:" line
  local what=$1; shift
  set +e; "$@" >/dev/null 2>"$tmp/err"; local code=$?; set -e
  if [ "$code" != 2 ] || grep -q Traceback "$tmp/err" || [ "$(grep -c . "$tmp/err")" != 1 ] ||
     ! grep -q "^cfvol: error: " "$tmp/err"; then
    echo "wheel check: $what: expected exit 2 and one error line, got exit $code:" >&2; cat "$tmp/err" >&2; exit 1
  fi
}
before=$(sha256sum run/summary.json)
refused "a second run into one folder" "$cfvol" simulate automotive_push --out run --scenario-text "{bounds: {certify: null}}"
test "$(sha256sum run/summary.json)" = "$before"
printf 'n\xe4me: cell\n' > latin1.yaml
refused "a workcell file that is not UTF-8" "$cfvol" plan latin1.yaml --path 1
refused "a time limit that is not finite" "$cfvol" plan automotive --path 1 --time-limit inf
echo "wheel check: OK"
