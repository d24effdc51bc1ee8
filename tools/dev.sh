#!/usr/bin/env bash
# Sets up (once) and uses a local virtual environment in the repository's
# .venv, then runs the given command inside it, in the caller's folder (so
# relative paths such as --out mean what they say). Used by the README's two
# commands and CI.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python3}
stamp="$ROOT/.venv/.installed-$(sha256sum "$ROOT/pyproject.toml" | cut -c1-16)"
if [ ! -f "$stamp" ]; then
  # pip's and setuptools' chatter goes to a log, shown only if the install fails.
  echo "dev.sh: installing drake_cfvol and its dependencies into $ROOT/.venv (once: about 20 s with a local package index, longer when it downloads)" >&2
  [ -x "$ROOT/.venv/bin/python" ] || "$PY" -m venv "$ROOT/.venv"
  log="$ROOT/.venv/install.log"
  if ! { "$ROOT/.venv/bin/python" -m pip install -q --upgrade pip &&
         "$ROOT/.venv/bin/python" -m pip install -q -e "$ROOT[test]"; } >"$log" 2>&1; then
    cat "$log" >&2
    echo "dev.sh: error: the install failed (log above, also in $log)" >&2
    exit 1
  fi
  rm -f "$ROOT"/.venv/.installed-*; touch "$stamp"
fi
cmd=$1
shift
exec "$ROOT/.venv/bin/$cmd" "$@"
