#!/usr/bin/env bash
# Install skelfuse with the development extras into ./.venv, then run what CI runs:
# ruff, mypy and the whole test suite (unit, loopback integration, end-to-end, browser).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh
ensure_venv
echo "==> installing skelfuse with the dev extras"
"$VENV/bin/pip" install --quiet --disable-pip-version-check -e '.[dev]'

if ! command -v chromium >/dev/null 2>&1; then
  echo "==> installing Debian's chromium for the viewer test"
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "warning: no chromium and no root: the browser tests will report themselves skipped" >&2
    echo "         (install it with: sudo apt-get install chromium)" >&2
  fi
fi

echo "==> ruff"
"$VENV/bin/ruff" check .
"$VENV/bin/ruff" format --check .
echo "==> mypy"
"$VENV/bin/python" scripts/typecheck_tree.py  # mypy reads the layers through these links
"$VENV/bin/mypy"
echo "==> pytest"
set +e
"$VENV/bin/python" -m pytest "$@"
status=$?
set -e
if [ "$status" -eq 5 ]; then
  echo "error: pytest collected no tests; that is a failure here, not a pass" >&2
  exit 1
fi
exit "$status"
