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
  [ -x "$ROOT/.venv/bin/python" ] || "$PY" -m venv "$ROOT/.venv"
  "$ROOT/.venv/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$ROOT/.venv/bin/python" -m pip install -q -e "$ROOT[test]"
  rm -f "$ROOT"/.venv/.installed-*; touch "$stamp"
fi
cmd=$1
shift
exec "$ROOT/.venv/bin/$cmd" "$@"
