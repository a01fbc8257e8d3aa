# tests/test_dls_noise.sh — noise of the dynamic light sets' records over seeds:
# estate_small (14 sets) baked at quality draft, 2 bounces, with seeds 1, 2 and 3, then
# `ubake spread --bound 4`: every texel pixel, GLG probe and LLG probe of every set's
# record lies within 4 × (|median over the seeds| + the record's mean |value|) of its
# median.
#
# Why: a set's full pass gathers with fewer rays where its influence pass found the set's
# light faint (scaled rays, bake/dls.c dls_ray_shift). A texel whose faint light comes from
# rare bright hits (a lit wall seen through a doorway) then carries one such hit at up to
# 2^UB_DLS_RAY_SHIFT_MAX times the weight it has at full rays. With the shift capped at 3
# (down to 1/8 of the rays, until 2026-11-28) the worst texel here is 6.09 (seeds 4-6:
# 5.32), and this test fails. Capped at 2: 2.96 (2.94); with full rays everywhere
# (--dls-full-rays) 1.91 (2.94: the draft estimator's own tail).
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = the build tree (levels/).
set -u

: "${UBAKE:?UBAKE must point to the ubake program}"
: "${UB_BUILD:?UB_BUILD must point to the build tree}"
level="$UB_BUILD/levels/estate_small.gltf"
out="$UB_BUILD/test_out/dls_noise"
rm -rf "$out"
mkdir -p "$out"
files=""
for seed in 1 2 3; do
  if ! "$UBAKE" bake "$level" -o "$out/seed$seed" --quality draft --bounces 2 --seed "$seed" --no-progress \
      >"$out/bake$seed.log" 2>&1; then
    echo "FAIL: bake of $level with seed $seed failed:" >&2
    tail -5 "$out/bake$seed.log" >&2
    exit 1
  fi
  files="$files $out/seed$seed/estate_small.ubk"
done
# shellcheck disable=SC2086 # the three paths, split on purpose
"$UBAKE" spread $files --bound 4 | tee "$out/spread.txt"
status=${PIPESTATUS[0]}
# not vacuous: every set's three representations were compared
for kind in "texel pixels" "GLG probes" "LLG probes"; do
  n=$(grep -c "^[a-z_0-9]*  *$kind  *[1-9][0-9]* receivers" "$out/spread.txt")
  [ "$n" -ge 14 ] || { echo "FAIL: $n '$kind' rows, want one per set (14)" >&2; status=1; }
done
[ "$status" -eq 0 ] || { echo "FAIL: a set record's spread over seeds is above 4" >&2; exit 1; }
echo "set records within the bound"
