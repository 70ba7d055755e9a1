#!/usr/bin/env bash
# Issue 33's CPU goals measured on 2 cores of an otherwise idle machine (`taskset -c 0,1`): the quick suite
# cold (wall, CPU, peak memory), then the Cornell-box audit with its references cached beside three plain
# `mi.render` processes of the same file, size and spp, alternated ROUNDS times after a warm-up.
# Usage: bash scripts/bench-two-cores.sh OUT_DIR [ROUNDS]   (prints one line per measurement)
set -uo pipefail
out=${1:?usage: bench-two-cores.sh OUT_DIR [ROUNDS]}; rounds=${2:-3}
mkdir -p "$out"
pin="taskset -c 0,1"
scene=tests/data/mitsuba/cbox/cbox-rgb.xml
stamp() { date +%s.%N; }
el() { awk "BEGIN{printf \"%.2f\", $2 - $1}"; }
if [ "${SKIP_QUICK:-0}" != 1 ]; then
  t0=$(stamp)
  /usr/bin/time -f "%e %U %S %M" -o "$out/quick.time" $pin rtfit run all --quick --out "$out/quick" \
    --cache "$out/quick-cache" --no-progress > "$out/quick.log" 2>&1
  echo "quick suite: exit $? wall $(el "$t0" "$(stamp)") s; time -f '%e %U %S %M(KiB)': $(cat "$out/quick.time")"
fi
audit() { $pin rtfit audit "$scene" -D res=64 --spp 32 --out "$out/audit" --cache "$out/audit-cache" --no-progress "$@"; }
render() {
  for _ in 1 2 3; do
    $pin python3 -c "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); \
s = mi.load_file('$scene', res=64); import drjit as dr; dr.eval(mi.render(s, spp=32))"
  done
}
audit --profile > "$out/audit-cold.log" 2>&1
echo "audit cold: $(grep -m1 '^timings:' "$out/audit-cold.log")"
render > /dev/null 2>&1
for r in $(seq "$rounds"); do
  t0=$(stamp); audit > /dev/null 2>&1; t1=$(stamp); render > /dev/null 2>&1; t2=$(stamp)
  echo "round $r: audit (cached) $(el "$t0" "$t1") s, three mi.render $(el "$t1" "$t2") s, ratio $(awk "BEGIN{printf \"%.1f\", ($t1-$t0)/($t2-$t1)}")"
done
