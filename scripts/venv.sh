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

# install_debian_package PACKAGE WHY: for a missing system library or tool, install the Debian
# package when we may (root, or passwordless sudo); otherwise warn and go on, since what needs it
# reports itself (a skipped browser test, an ICP calibration that names the library).
install_debian_package() {
  local package="$1" why="$2" sudo=""
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
      sudo="sudo"
    else
      echo "warning: $package is missing and we are not root: $why" >&2
      echo "         (install it with: sudo apt-get install $package)" >&2
      return 0
    fi
  fi
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "warning: $package is missing and there is no apt-get: $why" >&2
    return 0
  fi
  echo "==> installing Debian's $package: $why"
  if [ -z "${_SKELFUSE_APT_UPDATED:-}" ]; then
    $sudo apt-get update -qq
    _SKELFUSE_APT_UPDATED=1
  fi
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$package" >/dev/null
}

# open3d (server extras, ICP calibration) links libusb-1.0 and does not import without it.
ensure_libusb() {
  # grep reads to the end (no -q): with pipefail, ldconfig cut off by SIGPIPE would count as absent
  if { ldconfig -p || /sbin/ldconfig -p; } 2>/dev/null | grep 'libusb-1\.0\.so\.0' >/dev/null; then
    return 0
  fi
  install_debian_package libusb-1.0-0 "open3d (ICP calibration) needs it to import"
}
