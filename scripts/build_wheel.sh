#!/usr/bin/env bash
# Build skelfuse's wheel into DIR (default dist/) from the sources alone: the files git tracks or
# would track, copied to a temporary folder first. Building in the checkout would let
# setuptools pack whatever an earlier build left in build/lib (a module since moved or deleted).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh
out="$(mkdir -p "${1:-dist}" && cd "${1:-dist}" && pwd)"
ensure_venv
if ! git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  echo "error: build_wheel.sh lists the sources with git; run it in a git checkout" >&2
  exit 1
fi
src="$(mktemp -d "${TMPDIR:-/tmp}/skelfuse-src.XXXXXX")"
trap 'rm -rf "$src"' EXIT
# tracked and untracked-but-not-ignored files that exist (a deletion not yet committed is skipped)
git ls-files -z --cached --others --exclude-standard |
  while IFS= read -r -d '' file; do
    if [ -f "$file" ]; then printf '%s\0' "$file"; fi
  done |
  tar --null --files-from=- -cf - | tar -xf - -C "$src"
"$VENV/bin/python" -m pip wheel --quiet --no-deps --wheel-dir "$out" "$src"
ls "$out"/skelfuse-*.whl
