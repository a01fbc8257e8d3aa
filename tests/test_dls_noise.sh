# tests/test_dls_noise.sh — noise of the dynamic light sets' records over seeds:
# estate_small (14 sets) baked at quality draft, 2 bounces, with seeds 1, 2 and 3, then
# `ubake spread --bound 4`: every texel pixel, GLG probe and LLG probe of every set's
# record lies within 4 × (|median over the seeds| + the record's mean |value|) of its
# median, and at most 80 texel values (summed over the sets) lie over 0.5 of those units;
# the base bake's receivers (`--base`) within 2; the sets' two bounds again for the
# irradiance along each texel's normal (`--along-normal`); and bad arguments (one file, an
# unknown element, a negative bound, a missing file, a bake of another level) refused by
# name.
#
# Why: a set's full pass gathers with fewer rays where its influence pass found the set's
# light faint (scaled rays, bake/dls.c dls_ray_shift). A texel whose faint light comes from
# rare bright hits (a lit wall seen through a doorway) then carries one such hit at up to
# 8× the weight it has at full rays. Until 2026-11-28 the sets' passes took texel lights
# only where the base pass does (pass.c UB_TL_PEAK): worst 6.09 and 216 values over 0.5
# here (seeds 4-6: 5.32, 207), and this test fails on both counts. With the rays at least
# 1/4 instead of 1/8: 2.96 and 179; with full rays: 1.91 and 79. With texel lights in
# every block of the sets' passes (ub_pass_desc.texel_lights_everywhere): 1.29 and
# 26 (seeds 4-6: 2.93 and 32); with grazing gather rays' SH weight floored too
# (UB_SH_COS_FLOOR, bake/pass.h; now): 1.29 and 17.
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = the build tree (levels/).
set -u
# shellcheck source=tests/seed_bakes.sh
. "$(dirname "$0")/seed_bakes.sh"

: "${UBAKE:?UBAKE must point to the ubake program}"
: "${UB_BUILD:?UB_BUILD must point to the build tree}"
level="$UB_BUILD/levels/estate_small.gltf"
out="$UB_BUILD/test_out/dls_noise"
rm -rf "$out"
mkdir -p "$out"
bake_seeds "$level" "$out" estate_small --quality draft --bounces 2
# shellcheck disable=SC2086 # the three paths, split on purpose
"$UBAKE" spread $files --bound 4 | tee "$out/spread.txt"
status=${PIPESTATUS[0]}
# not vacuous: every set's three representations were compared
for kind in "texel pixels" "GLG probes" "LLG probes"; do
  n=$(grep -c "^[a-z_0-9]*  *$kind  *[1-9][0-9]* receivers" "$out/spread.txt")
  [ "$n" -ge 14 ] || { echo "FAIL: $n '$kind' rows, want one per set (14)" >&2; status=1; }
done
# over_half FILE: the texel pixels' "N over 0.5" of a spread output, summed over its rows
over_half() {
  awk '/ texel pixels / { for (i = 1; i < NF; i++) if ($(i + 1) == "over" && $(i + 2) ~ /^0\.5,?$/) s += $i } END { print s + 0 }' "$1"
}
over=$(over_half "$out/spread.txt")
echo "texel values over 0.5, summed over the sets: $over (bound 80)"
[ "$over" -le 80 ] || { echo "FAIL: $over texel values over 0.5 (bound 80)" >&2; status=1; }
# The base bake over the same seeds (spread --base): 0.57 here, 1 value over 0.5.
"$UBAKE" spread $files --base --element "(base)" --bound 2 | tee "$out/spread_base.txt"
[ "${PIPESTATUS[0]}" -eq 0 ] || { echo "FAIL: the base bake's spread over seeds is above 2" >&2; status=1; }
for kind in "texel pixels" "GLG probes" "LLG probes"; do
  grep -q "^(base)  *$kind  *[1-9][0-9]* receivers" "$out/spread_base.txt" ||
    { echo "FAIL: no '$kind' row for the base bake" >&2; status=1; }
done
# What a flat surface shows (spread --along-normal: the irradiance along each texel's
# normal, which UB_SH_COS_FLOOR does not touch): 1.32 here, 25 values over 0.5.
"$UBAKE" spread $files --along-normal --bound 4 | tee "$out/spread_normal.txt"
[ "${PIPESTATUS[0]}" -eq 0 ] || { echo "FAIL: the sets' irradiance along the normal spreads above 4" >&2; status=1; }
grep -q "; texel values along the normal" "$out/spread_normal.txt" ||
  { echo "FAIL: spread --along-normal does not say it reads along the normal" >&2; status=1; }
over=$(over_half "$out/spread_normal.txt")
echo "texel values along the normal over 0.5, summed over the sets: $over (bound 80)"
[ "$over" -le 80 ] || { echo "FAIL: $over values along the normal over 0.5 (bound 80)" >&2; status=1; }
# Bad input: exit status 1 and a message naming what is wrong.
bad() { # bad EXPECTED-STDERR-TEXT ARGS...
  local want="$1"
  shift
  if "$UBAKE" spread "$@" >"$out/bad.out" 2>"$out/bad.err"; then
    echo "FAIL: ubake spread $* exited 0" >&2
    status=1
  elif ! grep -qF -- "$want" "$out/bad.err"; then
    echo "FAIL: ubake spread $*: stderr lacks '$want': $(cat "$out/bad.err")" >&2
    status=1
  fi
}
one="$out/seed1/estate_small.ubk"
bad "give two or more" "$one"
bad "no element named nope" "$one" "$out/seed2/estate_small.ubk" --element nope
bad "--bound -1" "$one" "$out/seed2/estate_small.ubk" --bound -1
bad "$out/missing.ubk" "$one" "$out/missing.ubk"
if "$UBAKE" bake "$UB_BUILD/levels/furnace.gltf" -o "$out/other" --quality draft --no-progress \
    >"$out/bake_other.log" 2>&1; then
  bad "$out/other/furnace.ubk: not a bake of the level of $one" "$one" "$out/other/furnace.ubk"
else
  echo "FAIL: bake of furnace.gltf failed" >&2
  status=1
fi
[ "$status" -eq 0 ] || { echo "FAIL: a spread over seeds is above its bounds, or bad input passed" >&2; exit 1; }
echo "set records within the bound"
