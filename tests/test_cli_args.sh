# tests/test_cli_args.sh — the ubake commands' argument errors name what is wrong (the
# option, the files), `info --json` escapes the names a level gives, and a weight past
# UB_RUNTIME_MAX_WEIGHT is refused instead of read as 0 by the GLG.
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
"$UBAKE" bake "$tmpdir/hw.gltf" -o "$tmpdir/b" --quality draft --bounces 1 --threads 1 \
  --no-progress >/dev/null 2>"$tmpdir/bake.err" || {
  cat "$tmpdir/bake.err" >&2
  echo "FAIL: cannot bake the hallway" >&2
  exit 1
}
ubk="$tmpdir/b/hw.ubk"

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
# Weights: past 1e6 refused (the GLG read 0 for 1e30), 1e6 answered.
expect weight_huge 1 "0 <= W <= 1e6" -- query "$ubk" --at 0,1,0 --normal 0,1,0 --dls hall_b=1e30
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
