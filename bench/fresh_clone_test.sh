#!/usr/bin/env bash
# Wall time of a fresh clone's `make test` (install included), as CI runs it: the issue 23
# target is ≤ 3 min 30 s on the 2-core machine. Run from a checkout:
#     bench/fresh_clone_test.sh            # clones HEAD into a temporary folder, times `make test`
# Every user cache is fresh for the run (XDG_CACHE_HOME: numba's compile cache, uv's downloads),
# as on a fresh machine; the system packages (apt) are whatever this machine has.
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
git clone -q "$src" "$work/endocam"
cd "$work/endocam"
export XDG_CACHE_HOME="$work/cache"   # endocam's numba cache folder lives under it
start=$(date +%s)
make test
end=$(date +%s)
echo "fresh clone make test: $((end - start)) s wall"
times  # user and system CPU of this shell, then of its children (make, pytest, ...)
