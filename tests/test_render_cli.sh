# tests/test_render_cli.sh — `ubake render` as an artist runs it: a PNG of the asked size,
# a warning (and still the PNG) when the camera sees back faces or nothing, exit status 1
# and no PNG for a bad camera, an unknown set or an -o that is not .png; the load's notes
# on stderr, stdout only what was written.
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = the build tree (its levels/).
. "$(dirname "$0")/cli_lib.sh" render_cli

# The PNG's width and height (IHDR, big-endian at bytes 16..23) as "WxH".
png_size() {
  local w h
  w=$(od -An -tu1 -j16 -N4 "$1" | awk '{print $1 * 16777216 + $2 * 65536 + $3 * 256 + $4}')
  h=$(od -An -tu1 -j20 -N4 "$1" | awk '{print $1 * 16777216 + $2 * 65536 + $3 * 256 + $4}')
  echo "${w}x${h}"
}

"$UBAKE" bake "$build/levels/cornell.gltf" -o "$tmpdir/cb" --quality draft --bounces 1 \
  --threads 1 --no-progress >/dev/null 2>"$tmpdir/bake.err" || {
  cat "$tmpdir/bake.err" >&2
  echo "FAIL: cannot bake cornell" >&2
  exit 1
}
ubk="$tmpdir/cb/cornell.ubk"

# render NAME EXPECTED_STATUS ARGS...: runs it, stderr in $tmpdir/NAME.err
render() {
  local name="$1" want="$2" status
  shift 2
  "$UBAKE" render "$ubk" -o "$tmpdir/$name.png" "$@" >"$tmpdir/$name.out" 2>"$tmpdir/$name.err"
  status=$?
  [ "$status" -eq "$want" ] || fail "$name: exit status $status, expected $want: $(cat "$tmpdir/$name.err")"
  echo "$name: status $status: $(head -c 300 "$tmpdir/$name.err")"
}

# Inside the box: a clean run, the size asked for.
render inside 0 --camera 0,1,0.95,0,1,-1,70 --size 64x48
[ -s "$tmpdir/inside.err" ] && fail "inside: unexpected stderr: $(cat "$tmpdir/inside.err")"
[ -f "$tmpdir/inside.png" ] && [ "$(png_size "$tmpdir/inside.png")" = "64x48" ] ||
  fail "inside: no 64x48 PNG"

# Outside the closed box: its back faces and the void; the PNG is still written.
render outside 0 --camera 0,1,5,0,1,0,40 --size 64x48
grep -q "warning: .*outside.png: only 0% of the view meets front faces" "$tmpdir/outside.err" &&
  grep -qF "(0, 1, 5)" "$tmpdir/outside.err" ||
  fail "outside: no warning naming the view and the camera: $(cat "$tmpdir/outside.err")"
[ -f "$tmpdir/outside.png" ] || fail "outside: no PNG"

# Bad input: a camera looking at itself, a set the file does not have: no PNG.
render same_point 1 --camera 0,1,0,0,1,0,60
grep -q "eye and target" "$tmpdir/same_point.err" || fail "same_point: the message does not say what is wrong"
[ -e "$tmpdir/same_point.png" ] && fail "same_point: a PNG was written"
render no_set 1 --camera 0,1,0.95,0,1,-1,70 --dls no_such_set=0
grep -qF "no_such_set" "$tmpdir/no_set.err" || fail "no_set: the message does not name the set"
[ -e "$tmpdir/no_set.png" ] && fail "no_set: a PNG was written"

# -o must name a .png (any case): a .jpg is refused before any work, naming the path.
"$UBAKE" render "$ubk" --camera 0,1,0.95,0,1,-1,70 -o "$tmpdir/shot.jpg" >/dev/null 2>"$tmpdir/jpg.err" &&
  fail "jpg: an -o ending in .jpg was taken"
grep -qF "not '$tmpdir/shot.jpg'" "$tmpdir/jpg.err" && grep -qF ".png" "$tmpdir/jpg.err" ||
  fail "jpg: the message does not name the path and .png: $(cat "$tmpdir/jpg.err")"
[ -e "$tmpdir/shot.jpg" ] && fail "jpg: a file was written"
"$UBAKE" render "$ubk" --camera 0,1,0.95,0,1,-1,70 --size 16x8 -o "$tmpdir/upper.PNG" >/dev/null \
  2>"$tmpdir/upper.err" && [ -f "$tmpdir/upper.PNG" ] || fail "upper: no .PNG written: $(cat "$tmpdir/upper.err")"

# A load with a note (the hallway's merged texel groups): on stderr, not stdout.
"$UBAKE" bake "$build/levels/hallway.gltf" -o "$tmpdir/hw" --quality draft --bounces 1 \
  --threads 1 --no-progress >/dev/null 2>&1 || fail "cannot bake the hallway"
"$UBAKE" render "$tmpdir/hw/hallway.ubk" --camera 0,1,0,0,1,1,60 --size 32x16 -o "$tmpdir/hw.png" \
  >"$tmpdir/hw.out" 2>"$tmpdir/hw.err" || fail "hallway render failed: $(cat "$tmpdir/hw.err")"
grep -q "^ubake: note: .*hallway.ubk: " "$tmpdir/hw.err" ||
  fail "hallway: no load note on stderr (does the hallway's load still print one?): $(cat "$tmpdir/hw.err")"
grep -v "^rendered \|^load " "$tmpdir/hw.out" | grep -q . &&
  fail "hallway: stdout holds more than what was written: $(cat "$tmpdir/hw.out")"
ls "$tmpdir" | grep -q '\.tmp$' && fail "a temporary PNG was left behind"

finish "all render CLI checks passed"
