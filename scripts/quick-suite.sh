#!/usr/bin/env bash
# The main job: set up, then run every experiment's quick configuration on the CPU (LLVM backend)
# and write a report. Extra arguments go to `rtfit run` (e.g. --out DIR, --variant cuda_ad_rgb).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bootstrap.sh"
cd "$RTFIT_ROOT"
exec rtfit run all --quick "$@"
