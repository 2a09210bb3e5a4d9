# Sourced by the scripts: find Python 3.11+ and make ./.venv (or $SKELFUSE_VENV).
VENV="${SKELFUSE_VENV:-.venv}"

ensure_venv() {
  if [ -x "$VENV/bin/python" ] && [ -x "$VENV/bin/pip" ] &&
     "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
    return
  fi
  if [ -e "$VENV" ]; then
    # A virtualenv whose creation was interrupted (Ctrl-C during the first run) has a python
    # but no pip: make it again rather than fail on every later run.
    echo "==> $VENV is incomplete (no pip); making it again"
    rm -rf "$VENV"
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

# install_debian_packages WHY PACKAGE...: install Debian packages a tool or library needs when we
# may (root, or passwordless sudo); otherwise warn and go on, since what needs them reports itself
# (a skipped browser test, an ICP calibration that names the library).
install_debian_packages() {
  local why="$1" sudo=""
  shift
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
      sudo="sudo"
    else
      echo "warning: $* missing and we are not root: $why" >&2
      echo "         (install with: sudo apt-get install $*)" >&2
      return 0
    fi
  fi
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "warning: $* missing and there is no apt-get: $why" >&2
    return 0
  fi
  echo "==> installing Debian's $*: $why"
  if [ -z "${_SKELFUSE_APT_UPDATED:-}" ]; then
    $sudo apt-get update -qq
    _SKELFUSE_APT_UPDATED=1
  fi
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

# open3d (server extras, ICP calibration) does not import without the system libraries it links,
# and minimal Debian lacks some: libusb-1.0 nearly always, the GL and X11 ones on servers and in
# containers. SONAME:PACKAGE pairs; the Dockerfile and calibration/open3d_loader.py name the same.
OPEN3D_LIBRARIES="libusb-1.0.so.0:libusb-1.0-0 libGL.so.1:libgl1 libEGL.so.1:libegl1
  libX11.so.6:libx11-6 libudev.so.1:libudev1"

ensure_open3d_libraries() {
  local known entry missing=()
  known="$({ ldconfig -p || /sbin/ldconfig -p; } 2>/dev/null | awk '{print $1}')"
  for entry in $OPEN3D_LIBRARIES; do
    if ! grep -Fx "${entry%%:*}" >/dev/null <<<"$known"; then
      missing+=("${entry#*:}")
    fi
  done
  if [ "${#missing[@]}" -gt 0 ]; then
    install_debian_packages "open3d (ICP calibration) does not import without them" "${missing[@]}"
  fi
}
