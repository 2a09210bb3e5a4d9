#!/usr/bin/env bash
# Make ./.venv-mono (or $SKELFUSE_VENV_MONO): the environment of the `mono` source (one RGB camera,
# agent/sources/mono.py), with skelfuse installed into it. Used by scripts/test.sh so CI runs the
# source's integration test (tests/integration/test_mono_source.py) with the real model.
#
# Why a second environment: mediapipe 0.10.21, the one pose package on PyPI whose wheel ships its
# models (nothing may download weights at run time), pins numpy<2, and the main and dev
# environments are on numpy 2. Its metadata also pulls jax, opencv-contrib and more (a 990 MB
# venv); the pose solution runs with only the packages below (412 MB), so mediapipe goes in with
# --no-deps and its real needs are named here. pyproject.toml's `mono` extra says the same for
# a plain `pip install "skelfuse[mono]"` on an agent PC (the full 990 MB set).
set -euo pipefail
cd "$(dirname "$0")/.."
MONO_VENV="${SKELFUSE_VENV_MONO:-.venv-mono}"
MONO_PACKAGES=(
  "numpy>=1.26,<2" "protobuf>=4.25,<5" absl-py attrs flatbuffers matplotlib
  "opencv-python-headless>=4.8"
  # skelfuse's own base dependencies (the agent: numpy, pyzmq, msgpack, threadpoolctl)
  "pyzmq>=26" "msgpack>=1.0.7" "threadpoolctl>=3.1"
  # the integration test runs under pytest in this environment
  "pytest>=8" "pytest-timeout>=2.3"
)

python=""
for candidate in python3.11 python3.12 python3; do  # mediapipe 0.10.21 has cp39-cp312 wheels
  if command -v "$candidate" >/dev/null 2>&1 &&
     "$candidate" -c 'import sys; sys.exit(not ((3, 11) <= sys.version_info[:2] <= (3, 12)))'; then
    python="$candidate"
    break
  fi
done
if [ -z "$python" ]; then
  echo "warning: no Python 3.11 or 3.12 for mediapipe 0.10.21: $MONO_VENV not made" >&2
  echo "         (the mono source's integration test skips, and fails under CI)" >&2
  exit 0
fi
if ! [ -x "$MONO_VENV/bin/python" ] || ! "$MONO_VENV/bin/python" -m pip --version >/dev/null 2>&1; then
  rm -rf "$MONO_VENV"
  echo "==> creating $MONO_VENV with $($python --version) (the mono source: mediapipe, numpy<2)"
  "$python" -m venv "$MONO_VENV"
  "$MONO_VENV/bin/pip" install --quiet --disable-pip-version-check --upgrade pip
fi
pip_install() { "$MONO_VENV/bin/pip" install --quiet --disable-pip-version-check "$@"; }
echo "==> installing mediapipe 0.10.21 (without its optional heavy dependencies) into $MONO_VENV"
pip_install --no-deps "mediapipe==0.10.21"
# pip then reports mediapipe's declared but unneeded dependencies (jax, jaxlib,
# opencv-contrib-python, sentencepiece, sounddevice) as "not installed": expected, on purpose.
pip_install "${MONO_PACKAGES[@]}"
# skelfuse itself, editable so the tests see this tree, without its dependencies: the base ones
# are above (numpy<2 must stay; pip would not downgrade, but it would resolve them again).
pip_install --no-deps -e .
"$MONO_VENV/bin/python" -c 'import mediapipe, numpy, skelfuse.agent.sources.registry' \
  || { echo "error: $MONO_VENV does not import mediapipe and skelfuse" >&2; exit 1; }
echo "==> $MONO_VENV ready (mediapipe $("$MONO_VENV/bin/python" -c 'import mediapipe; print(mediapipe.__version__)'))"
