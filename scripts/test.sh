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
  install_debian_package chromium "the viewer's browser tests need it (skipped without it)"
fi
ensure_libusb

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
