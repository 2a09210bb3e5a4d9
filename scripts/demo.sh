#!/usr/bin/env bash
# Install skelfuse (server extras) into ./.venv and run the live demo:
# the fusion server, simulated Kinect agents and the browser viewer. Ctrl-C stops everything.
# Extra arguments go to `skelfuse demo` (e.g. --sensors 4 --persons 3; --data DIR to keep keys and
# calibration for the next run; --access-log for a line per HTTP request). Once it fuses, the
# last lines are the viewer's address with its token, in a box.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh
ensure_venv
ensure_open3d_libraries
echo "==> installing skelfuse with the server extras"
"$VENV/bin/pip" install --quiet --disable-pip-version-check -e '.[server]'
exec "$VENV/bin/skelfuse" demo "$@"
