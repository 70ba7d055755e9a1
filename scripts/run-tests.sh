#!/usr/bin/env bash
# The test suite: set up, then pytest. Extra arguments go to pytest.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bootstrap.sh"
cd "$RTFIT_ROOT"
exec python -m pytest "$@"
