#!/usr/bin/env bash
# The test suite: set up, then pytest. Extra arguments go to pytest.
# With no arguments (the README's command and CI) the suite runs on every core through pytest-xdist,
# one test file per worker at a time (--dist loadfile), so a module's expensive fixtures (renders, SDF
# bakes) are built once. RTFIT_TEST_WORKERS overrides the worker count (1: no xdist at all).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bootstrap.sh"
cd "$RTFIT_ROOT"
if [ "$#" -eq 0 ]; then
  workers="${RTFIT_TEST_WORKERS:-$(nproc)}"
  if [ "$workers" -gt 1 ]; then
    set -- -n "$workers" --dist loadfile
  fi
fi
exec python -m pytest "$@"
