#!/usr/bin/env bash
# What the Docker image does, without a Docker engine: build the wheel, install it with the
# server extras into a clean virtualenv outside the checkout, check that the install adds one
# top-level import package (skelfuse), compile the fusion kernels into a cache folder, then
# start `skelfuse server` from an empty folder and expect 200 from /api/health and the kernels
# loaded from that cache. The folder holds decoys named like the old top-level packages
# (server.py, protocol/), which would run if anything still imported them by those names.
#
# Dependencies are installed offline from a wheelhouse (build/wheelhouse, or
# $SKELFUSE_WHEELHOUSE) when it has them; otherwise it is filled from the index first, so open3d
# and the rest (~200 MB) are downloaded once, not on every run.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh
ensure_venv
wheelhouse="${SKELFUSE_WHEELHOUSE:-$PWD/build/wheelhouse}"
health_timeout_s=60
work="$(mktemp -d "${TMPDIR:-/tmp}/skelfuse-smoke.XXXXXX")"
server_pid=""
cleanup() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT
fail() {
  echo "error: wheel smoke test: $*" >&2
  if [ -s "$work/server.log" ]; then
    echo "---- server log ----" >&2
    cat "$work/server.log" >&2
    echo "--------------------" >&2
  fi
  exit 1
}

echo "==> wheel smoke: building the wheel"
wheel="$(bash scripts/build_wheel.sh "$work/dist")"
requirement="skelfuse[server] @ file://$wheel"

echo "==> wheel smoke: installing it with the server extras into $work/venv"
"$VENV/bin/python" -m venv "$work/venv"
# --no-compile: byte-compiling ~800 MB of dependencies would double the time, for one start
pip=("$work/venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-compile)
started=$SECONDS
if ! "${pip[@]}" --no-index --find-links "$wheelhouse" "$requirement" >/dev/null 2>&1; then
  echo "    filling the wheelhouse $wheelhouse (once; later runs install from it offline)"
  mkdir -p "$wheelhouse"
  "$work/venv/bin/python" -m pip wheel -qq --disable-pip-version-check \
    --wheel-dir "$wheelhouse" --find-links "$wheelhouse" "$requirement" ||
    fail "could not fetch the server extras' wheels"
  rm -f "$wheelhouse"/skelfuse-*.whl  # dependencies only: the wheel under test comes from $wheel
  "${pip[@]}" --no-index --find-links "$wheelhouse" "$requirement" ||
    fail "could not install $requirement"
fi
echo "    installed in $((SECONDS - started)) s"

# Every run below starts in an empty folder with decoys; `python -c` puts that folder first on
# sys.path, so a bare `import server` or `import protocol` anywhere would hit a decoy.
run="$work/run"
mkdir -p "$run/protocol"
for decoy in "$run/server.py" "$run/agent.py" "$run/protocol/__init__.py"; do
  echo 'raise SystemExit("decoy imported: a module still imports a top-level layer name")' \
    >"$decoy"
done
cd "$run"

echo "==> wheel smoke: one top-level package, and every module imports"
"$work/venv/bin/python" -c '
import importlib, pkgutil, sys
from importlib.metadata import distribution

files = distribution("skelfuse").files or []
tops = {f.parts[0] for f in files if f.parts[0] != ".." and not f.parts[0].endswith(".dist-info")}
if tops != {"skelfuse"}:
    sys.exit(f"the install adds top-level {sorted(tops)}, expected only skelfuse")
import skelfuse

names = [
    m.name
    for m in pkgutil.walk_packages(skelfuse.__path__, "skelfuse.")
    if not m.name.endswith(".__main__")  # runs the command line
]
for name in names:
    importlib.import_module(name)
print(f"    {len(files)} files under skelfuse/ and its dist-info; {len(names)} modules import")
' || fail "the installed distribution is not what it should be"

echo "==> wheel smoke: the fusion kernels compiled once, as the image's build does"
# The Dockerfile's command, with its cache folder (NUMBA_CACHE_DIR) in the work folder: the
# server started below must find the machine code there instead of compiling again.
export NUMBA_CACHE_DIR="$work/numba-cache"
started=$SECONDS
"$work/venv/bin/python" -c "from skelfuse.fusion.engine import warm_up; warm_up()" ||
  fail "the installed server extras do not compile the fusion stages (numba)"
echo "    compiled in $((SECONDS - started)) s"

echo "==> wheel smoke: skelfuse server from an empty folder"
ports="$("$work/venv/bin/python" -c '
import socket
socks = [socket.socket() for _ in range(2)]
for s in socks:
    s.bind(("127.0.0.1", 0))
print(*(s.getsockname()[1] for s in socks))
')"
read -r http_port zmq_port <<<"$ports"
"$work/venv/bin/skelfuse" server --http "127.0.0.1:$http_port" --zmq "tcp://127.0.0.1:$zmq_port" \
  --data "$work/data" >"$work/server.log" 2>&1 &
server_pid=$!
url="http://127.0.0.1:$http_port/api/health"
deadline=$((SECONDS + health_timeout_s))
until "$work/venv/bin/python" -c '
import sys, urllib.request
with urllib.request.urlopen(sys.argv[1], timeout=2) as reply:
    sys.exit(reply.status != 200)
' "$url" 2>/dev/null; do
  if ! kill -0 "$server_pid" 2>/dev/null; then
    wait "$server_pid" && status=0 || status=$?
    server_pid=""
    fail "skelfuse server exited with status $status before $url answered"
  fi
  if [ "$SECONDS" -ge "$deadline" ]; then
    fail "no 200 from $url within $health_timeout_s s"
  fi
  sleep 0.5
done
echo "    200 from $url"
ready="$(grep -o 'fusion kernels ready in [0-9.]* s' "$work/server.log" || true)"
[ -n "$ready" ] || fail "the server did not report its fusion kernels ready"
seconds="${ready#fusion kernels ready in }"
seconds="${seconds% s}"
"$work/venv/bin/python" -c 'import sys; sys.exit(float(sys.argv[1]) >= 5.0)' "$seconds" ||
  fail "the server took $seconds s to load the fusion kernels: it compiled them again"
echo "    $ready (from the cache)"

kill -TERM "$server_pid"
for _ in $(seq 50); do
  kill -0 "$server_pid" 2>/dev/null || break
  sleep 0.2
done
if kill -0 "$server_pid" 2>/dev/null; then
  kill -KILL "$server_pid"
  fail "skelfuse server did not stop within 10 s of SIGTERM"
fi
wait "$server_pid" && status=0 || status=$?
server_pid=""
# uvicorn shuts down cleanly, then re-raises SIGTERM so its parent sees how it ended: 128 + 15
if [ "$status" -ne 0 ] && [ "$status" -ne 143 ]; then
  fail "skelfuse server exited with status $status on SIGTERM"
fi
echo "==> wheel smoke: passed"
