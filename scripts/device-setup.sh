#!/usr/bin/env bash
# Set up rtfit on the lent GPU machine (its Python 3.12 has numpy, jax, optimistix, scikit-image,
# matplotlib, but neither mitsuba nor drjit, and no network). Source it from the repository root:
#     source scripts/device-setup.sh
# Needs, carried with the command (device tool `carry`):
#   .device/mitsuba-drjit-cp312.tar.xz   bash ../shared/tools/pack-for-device.sh
#   .whl/*.whl                           pure-Python or cp312 wheels of rtfit's other dependencies
#                                        (click, tomli_w, OpenEXR, tqdm, flip_evaluator, markdown_it_py, mdurl)
#   .device-ray/ray-site-cp312.tar.xz    optional: Ray and its dependencies for cp312, unpacked
#                                        (built as described in docs/scale-out.md)
set -euo pipefail
RTFIT_SITE="${RTFIT_SITE:-/tmp/site}"
mkdir -p "$RTFIT_SITE"
tar -xJf .device/mitsuba-drjit-cp312.tar.xz -C "$RTFIT_SITE"
if [ -f .device-ray/ray-site-cp312.tar.xz ]; then
  tar -xJf .device-ray/ray-site-cp312.tar.xz -C "$RTFIT_SITE"
  chmod +x "$RTFIT_SITE"/ray/core/src/ray/gcs/gcs_server "$RTFIT_SITE"/ray/core/src/ray/raylet/raylet
fi
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$RTFIT_SITE" .whl/*.whl
python3 -m pip install -q --no-index --no-deps --no-build-isolation --no-compile --upgrade --target "$RTFIT_SITE" .
export PYTHONPATH="$RTFIT_SITE${PYTHONPATH:+:$PYTHONPATH}"
export PATH="$RTFIT_SITE/bin:$PATH"
set +euo pipefail
