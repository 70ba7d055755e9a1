#!/usr/bin/env bash
# Audit the real scenes of tests/data/real (issue 31) as a user would: the default `rtfit audit` at
# 64² × 32 spp, one scene after another, printing each one's exit status, wall time and the audit's own
# timings line. Usage: bash scripts/audit-real-scenes.sh OUT_DIR [FIRST [LAST]] [-- extra audit options]
# (FIRST/LAST: 1-based indices into the scene list below, to split the list over several calls;
# AUDIT_TIMEOUT_S: a limit per scene, exit 124 past it).
set -uo pipefail
out=${1:?usage: audit-real-scenes.sh OUT_DIR [FIRST [LAST]] [-- options]}; shift
first=${1:-1}; last=${2:-99}; shift $(( $# >= 2 ? 2 : $# ))
[ "${1:-}" = "--" ] && shift
real=tests/data/real
scenes=(
  "$real/mitsuba-data/docs/scenes/integrator_direct_both.xml"
  "$real/mitsuba-data/scenes/matpreview/matpreview.xml"
  "$real/mitsuba-data/tests/scenes/various_emitters/test_various_emitters_ptracer.xml"
  "$real/mitsuba-data/tests/scenes/participating_media/test_hetero_sigmat_volpath.xml"
  "$real/mitsuba-data/tests/scenes/participating_media/test_homo_dielectric_envmap_volpath.xml"
  "$real/mitsuba-data/tests/scenes/participating_media/test_homo_obj_inside_medium_volpath.xml"
  "$real/mitsuba-data/tests/scenes/instancing/test_instancing_path.xml"
  "$real/sionna/etoile/etoile.xml"
  "$real/mitsuba3-sunsky/teapot/teapot.xml"
  "$real/mitsuba-blender/test1/test1.xml"
  "$real/mitsuba-data/docs/scenes/medium_homogeneous_sss.xml"
)
mkdir -p "$out"
for i in "${!scenes[@]}"; do
  n=$((i + 1)); [ "$n" -lt "$first" ] || [ "$n" -gt "$last" ] && continue
  s=${scenes[$i]}; name=$(basename "$s" .xml)
  t0=$(date +%s.%N)
  timeout "${AUDIT_TIMEOUT_S:-0}" rtfit audit "$s" --width 64 --height 64 --spp 32 --out "$out" --cache "$out/cache" --no-progress --profile "$@" \
    > "$out/$name.log" 2>&1
  rc=$?
  t1=$(date +%s.%N)
  printf '%-45s exit %d  %6.1f s  %s\n' "$name" "$rc" "$(awk "BEGIN{print $t1 - $t0}")" \
    "$(grep -m1 '^timings:' "$out/$name.log")"
done
