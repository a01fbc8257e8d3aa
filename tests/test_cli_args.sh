# tests/test_cli_args.sh — the ubake commands' argument errors name what is wrong (the
# option, the value, the files, the names a file has), `info --json` escapes the names a
# level gives, a weight past UB_RUNTIME_MAX_WEIGHT is refused instead of read as 0 by the
# GLG, the bake's summary line agrees with its report, and `query` says when the point is
# far from what answered it.
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = the build tree (its levels/).
. "$(dirname "$0")/cli_lib.sh" cli_args

# expect NAME STATUS NEEDLE -- ARGS...: ubake ARGS exits with STATUS and stderr holds NEEDLE
expect() {
  local name="$1" want="$2" needle="$3" status
  shift 4
  "$UBAKE" "$@" >"$tmpdir/$name.out" 2>"$tmpdir/$name.err"
  status=$?
  [ "$status" -eq "$want" ] || fail "$name: exit status $status, expected $want"
  grep -qF -- "$needle" "$tmpdir/$name.err" ||
    fail "$name: stderr lacks \"$needle\": $(cat "$tmpdir/$name.err")"
  echo "$name: status $status: $(head -c 200 "$tmpdir/$name.err")"
}

# A hallway whose set hall_a is named with a quote, a backslash and a tab.
sed 's/"hall_a"/"hall \\"A\\" \\\\ x\\ty"/' "$build/levels/hallway.gltf" >"$tmpdir/hw.gltf"
cp "$build/levels/hallway.bin" "$tmpdir/hallway.bin"
"$UBAKE" bake "$tmpdir/hw.gltf" -o "$tmpdir/b" --quality draft --bounces 1 \
  --no-progress >"$tmpdir/bake.out" 2>"$tmpdir/bake.err" || {
  cat "$tmpdir/bake.err" >&2
  echo "FAIL: cannot bake the hallway" >&2
  exit 1
}
ubk="$tmpdir/b/hw.ubk"

# The summary line and the report agree: rays (rays.total, the sets' included; the hallway's
# lights are all in sets), seconds (the write stage included), peak RSS in MiB; the report
# names the threads used (default: all cores), not 0.
report="$tmpdir/b/hw.report.json"
line=$(grep '^baked hw: ' "$tmpdir/bake.out")
r_threads=$(sed -n 's/^  "threads": \([0-9]*\),$/\1/p' "$report")
r_seconds=$(sed -n 's/^  "seconds": \([0-9.]*\),$/\1/p' "$report")
r_rays=$(sed -n 's/^  "rays": {"total": \([0-9]*\),.*/\1/p' "$report")
r_mib=$(sed -n 's/^  "peak_rss_mib": \([0-9.]*\),$/\1/p' "$report")
[ -n "$r_threads" ] && [ "$r_threads" -ge 1 ] || fail "report: threads '$r_threads', expected the count used"
[ -n "$r_rays" ] && [ "$r_rays" -gt 0 ] || fail "report: rays.total '$r_rays'"
case "$line" in
  *", $(awk -v r="$r_rays" 'BEGIN { printf "%.2f", r / 1e6 }') M rays (base pass "*) ;;
  *) fail "summary line's rays are not the report's rays.total $r_rays: $line" ;;
esac
case "$line" in
  *", peak RSS $r_mib MiB, "*) ;;
  *) fail "summary line's peak RSS is not the report's $r_mib MiB: $line" ;;
esac
p_seconds=$(echo "$line" | sed -n 's/.*), \([0-9.]*\) s, peak RSS.*/\1/p')
awk -v p="$p_seconds" -v r="$r_seconds" 'BEGIN { exit !(p != "" && r != "" && p - r < 0.006 && r - p < 0.006) }' ||
  fail "summary line's ${p_seconds} s is not the report's seconds $r_seconds"
grep -q '"name": "write", "seconds"' "$report" || fail "report: no write stage"

# Options: the unknown one named, a known one missing its value named.
expect bake_unknown 1 "'--qualty'" -- bake "$tmpdir/hw.gltf" -o "$tmpdir/x" --qualty draft
expect bake_novalue 1 "option '--quality' lacks its value" -- bake "$tmpdir/hw.gltf" -o "$tmpdir/x" --quality
expect info_unknown 1 "unknown option '--jsn'" -- info --jsn "$ubk"
expect info_novalue 1 "option '--records' lacks its value" -- info "$ubk" --memory --records
expect render_novalue 1 "'--size'" -- render "$ubk" --camera 0,1,0,0,1,1,60 -o "$tmpdir/r.png" --size
expect query_unknown 1 "'--nrm'" -- query "$ubk" --at 0,1,0 --nrm 0,1,0
expect reference_unknown 1 "'--sp'" -- reference "$tmpdir/hw.gltf" --at 0,1,0 --normal 0,1,0 --sp 4
[ -e "$tmpdir/x" ] && fail "a failed bake created its output folder"
# One file per command.
expect info_two 1 "one file at a time: '$ubk' and 'other.ubk'" -- info "$ubk" other.ubk
expect query_two 1 "one file at a time" -- query "$ubk" "$ubk" --at 0,1,0 --normal 0,1,0
expect render_two 1 "one file at a time" -- render "$ubk" "$ubk" --camera 0,1,0,0,1,1,60 -o "$tmpdir/r.png"
expect reference_two 1 "one file at a time" -- reference "$tmpdir/hw.gltf" "$tmpdir/hw.gltf" --at 0,1,0 --normal 0,1,0
# Weights: past 1e6 refused (the GLG read 0 for 1e30), 1e6 answered; each message quotes
# the value. Decimal numbers only (no 0x), any finite one in range (a denormal is).
W_RULE="--dls takes NAME=W or NAME=R,G,B, W (or each of R,G,B) a decimal number in [0, 1e6]"
expect weight_huge 1 "$W_RULE, not 'hall_b=1e30'" -- query "$ubk" --at 0,1,0 --normal 0,1,0 --dls hall_b=1e30
for w in nan inf -1 1,-1,1 abc 0x10; do
  expect "weight_$w" 1 "$W_RULE, not 'hall_b=$w'" -- query "$ubk" --at 0,1,0 --normal 0,1,0 --dls "hall_b=$w"
done
expect render_weight 1 "$W_RULE, not 'hall_b=nan'" -- render "$ubk" --camera 0,1,0,0,1,1,60 -o "$tmpdir/r.png" --dls hall_b=nan
"$UBAKE" query "$ubk" --at 0,1,0 --normal 0,1,0 --dls hall_b=1e-310 >/dev/null 2>"$tmpdir/denormal.err" ||
  fail "weight 1e-310 (in range) refused: $(cat "$tmpdir/denormal.err")"
expect weight_twice 1 "dynamic light set 'hall_b' given twice" -- query "$ubk" --at 0,1,0 --normal 0,1,0 \
  --dls hall_b=1 --dls hall_b=0
expect at_nan 1 "--at takes X,Y,Z, each within +-1e7 m, not 'nan,0,0'" -- query "$ubk" --at nan,0,0 --normal 0,1,0
expect at_far 1 "--at takes X,Y,Z, each within +-1e7 m, not '1e8,0,0'" -- query "$ubk" --at 1e8,0,0 --normal 0,1,0
# An unknown set: the names the file has.
expect set_unknown 1 "no dynamic light set named 'HALL_B' in this file (it has 2: 'hall " -- \
  query "$ubk" --at 0,1,0 --normal 0,1,0 --dls HALL_B=1
grep -qF "'hall_b')" "$tmpdir/set_unknown.err" || fail "set_unknown: hall_b not listed"
expect door_unknown 1 "no door named 'd' in this file (it has none)" -- \
  query "$ubk" --at 0,1,0 --normal 0,1,0 --door d=1

# Far from what answered: a note on stderr, the answer on stdout; none at a point in the hall.
"$UBAKE" query "$ubk" --at 1000,1000,1000 --normal 0,1,0 --source lightmap >"$tmpdir/far.out" \
  2>"$tmpdir/far.err" || fail "far lightmap query failed: $(cat "$tmpdir/far.err")"
grep -qF "note: the closest lightmapped surface shown (triangle " "$tmpdir/far.err" &&
  grep -qF "from (1000, 1000, 1000)" "$tmpdir/far.err" ||
  fail "far lightmap query: no note of the distance: $(cat "$tmpdir/far.err")"
"$UBAKE" query "$ubk" --at 1000,1000,1000 --normal 0,1,0 >"$tmpdir/far.out" 2>"$tmpdir/far.err" ||
  fail "far GLG query failed: $(cat "$tmpdir/far.err")"
grep -qF "note: (1000, 1000, 1000) is outside the GLG probes' hull" "$tmpdir/far.err" ||
  fail "far GLG query: no note of the hull: $(cat "$tmpdir/far.err")"
[ "$(wc -l <"$tmpdir/far.out")" -eq 1 ] || fail "far GLG query: stdout is not one answer line"
for src in lightmap glg; do
  "$UBAKE" query "$ubk" --at 0,1,0 --normal 0,1,0 --source $src >/dev/null 2>"$tmpdir/near.err"
  grep -q "note: the closest\|outside the GLG" "$tmpdir/near.err" &&
    fail "query at 0,1,0 ($src): a far note: $(cat "$tmpdir/near.err")"
done
"$UBAKE" query "$ubk" --at 0,1,0 --normal 0,1,0 --dls hall_b=1e6 >"$tmpdir/q.out" 2>&1 ||
  fail "query with weight 1e6 failed: $(cat "$tmpdir/q.out")"
awk '{ if (!($1 > 1e3)) exit 1 }' "$tmpdir/q.out" || fail "weight 1e6 read $(cat "$tmpdir/q.out")"
# A long name: said so, not "--dls takes NAME=W".
expect long_name 1 "names are at most 63" -- query "$ubk" --at 0,1,0 --normal 0,1,0 \
  --dls "$(printf 'n%.0s' $(seq 70))=1"

# Lightmap warnings name a node: tests/data/uv_zero_area.gltf (a cornell box with
# TEXCOORD_1) has the floor's two triangles at zero UV area.
src="${UB_SOURCE:-$(cd "$(dirname "$0")/.." && pwd)}"
"$UBAKE" bake "$src/tests/data/uv_zero_area.gltf" -o "$tmpdir/uvz" --plan-only --threads 1 \
  --no-progress >/dev/null 2>"$tmpdir/uvz.err" || fail "uv_zero_area: plan failed: $(cat "$tmpdir/uvz.err")"
grep -qF "2 triangles with zero lightmap-UV area get no texels (the first: triangle 0 of node 'floor')" \
  "$tmpdir/uvz.err" || fail "uv_zero_area: the warning names no node: $(cat "$tmpdir/uvz.err")"

# info --json: the names escaped (a quote, a backslash, a tab as \u0009).
"$UBAKE" info "$ubk" --json >"$tmpdir/info.json" 2>"$tmpdir/info.err" || fail "info --json failed"
grep -qF '"name": "hall \"A\" \\ x\u0009y"' "$tmpdir/info.json" ||
  fail "info --json: the set's name is not escaped: $(grep -o '"dls": \[[^]]*' "$tmpdir/info.json" | head -c 300)"
grep -q "$(printf '\t')" "$tmpdir/info.json" && fail "info --json holds a raw tab"

finish "all argument checks passed"
