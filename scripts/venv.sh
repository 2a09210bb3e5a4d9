# Sourced by the scripts: find Python 3.11+ and make ./.venv (or $SKELFUSE_VENV).
VENV="${SKELFUSE_VENV:-.venv}"

ensure_venv() {
  if [ -x "$VENV/bin/python" ]; then
    return
  fi
  local python=""
  for candidate in python3.13 python3.12 python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1 &&
       "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
      python="$candidate"
      break
    fi
  done
  if [ -z "$python" ]; then
    echo "error: skelfuse needs Python 3.11 or newer (on Debian: apt-get install python3)" >&2
    exit 1
  fi
  echo "==> creating $VENV with $($python --version)"
  if ! "$python" -m venv "$VENV"; then
    echo "error: could not create a virtualenv (on Debian: apt-get install python3-venv)" >&2
    exit 1
  fi
  "$VENV/bin/pip" install --quiet --disable-pip-version-check --upgrade pip
}
