# tests/test_regress_cli.sh — `ubake regress` on bad input: every option checked before
# the bake (exit status 1, one stderr line naming the option and its value, nothing
# baked); golden files read and checked before the bake, written through PATH.tmp and a
# rename; --threads reaching the bake; and `ubake reference` refusing a point beyond the
# level loader's coordinate limit (it used to abort in Embree).
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = the build tree (its levels/).
. "$(dirname "$0")/cli_lib.sh" regress_cli
door="$build/levels/door_small.gltf"
box="$build/levels/cornell.gltf"
# Cheapest settings that still bake and trace: about a second per full run.
fast=(--threads 1 --spp 16 --texel-size 1)

# one_line NAME FILE: FILE holds exactly one line.
one_line() {
  local lines
  lines=$(wc -l <"$2")
  if ! { [ "$lines" -eq 1 ] || { [ "$lines" -eq 0 ] && [ -s "$2" ]; }; }; then
    fail "$1: stderr has $lines lines, expected 1:"
    sed 's/^/    /' "$2" >&2
  fi
}

# reject NAME PATTERN ARGS...: `ubake regress ARGS` (run in its own empty folder) exits 1
# with one stderr line matching PATTERN (grep -E) and bakes nothing.
reject() {
  local name="$1" pattern="$2" dir="$tmpdir/$1" status
  shift 2
  mkdir -p "$dir"
  (cd "$dir" && "$UBAKE" regress "$@" >stdout 2>stderr)
  status=$?
  [ "$status" -eq 1 ] || fail "$name: exit status $status, expected 1"
  one_line "$name" "$dir/stderr"
  grep -qE -- "$pattern" "$dir/stderr" ||
    fail "$name: stderr does not match '$pattern': $(cat "$dir/stderr")"
  [ -n "$(find "$dir" -mindepth 1 -type d -print -quit)" ] &&
    fail "$name: something was baked: $(find "$dir" -mindepth 1 -type d)"
  echo "$name: status $status: $(head -c 200 "$dir/stderr")"
}

# --- options, each checked before the bake ------------------------------------------
reject spp_negative "^ubake regress: --spp -5: .*1\.\.1073741824" "$door" --spp -5 --threads 1
reject spp_exponent "--spp 5e9: " "$door" --spp 5e9 --threads 1
reject spp_junk "--spp abc: " "$door" --spp abc --threads 1
reject spp_zero "--spp 0: " "$door" --spp 0 --threads 1
reject spp_wrapped "--spp 4294967291: " "$door" --spp 4294967291 --threads 1
reject spp_too_many "--spp 1073741825: " "$door" --spp 1073741825 --threads 1
reject spp_missing "--spp: missing value" "$door" --threads 1 --spp
reject quality_bogus "--quality bogus: takes draft, fast or high" "$door" --quality bogus
reject quality_missing "--quality: missing value" "$door" --quality
reject texel_junk "--texel-size abc: takes a positive number" "$door" --texel-size abc
reject texel_negative "--texel-size -1: " "$door" --texel-size -1
reject texel_zero "--texel-size 0: " "$door" --texel-size 0
reject texel_underflow "--texel-size 1e-50: " "$door" --texel-size 1e-50
reject texel_inf "--texel-size inf: " "$door" --texel-size inf
reject texel_suffix "--texel-size 0.5m: " "$door" --texel-size 0.5m
reject threads_zero "--threads 0: takes 1\.\.1024" "$door" --threads 0
reject threads_junk "--threads x2: " "$door" --threads x2
reject threads_many "--threads 4096: " "$door" --threads 4096
reject threads_missing "--threads: missing value" "$door" --threads
reject out_missing "-o: missing value" "$door" -o
reject out_empty "-o: missing value" "$door" -o ""
reject golden_missing_value "--golden: missing value" "$door" --golden
reject write_golden_missing_value "--write-golden: missing value" "$door" --write-golden
reject unknown "--bogus: unknown option" "$door" --bogus
reject two_levels "more than one level" "$door" "$box"
reject no_level "no level given" --spp 16

# --- golden files, before the bake ---------------------------------------------------
reject golden_absent "missing\.txt: cannot read the golden file: No such file" \
  "$door" "${fast[@]}" --golden missing.txt
printf '# comment\n0 0.001 0.002\n1 abc 0.002\n' >"$tmpdir/bad_golden.txt"
reject golden_malformed "bad_golden\.txt:3: expected" "$door" "${fast[@]}" \
  --golden "$tmpdir/bad_golden.txt"
printf '0 0.001 0.002\n0 0.001 0.002\n' >"$tmpdir/twice_golden.txt"
reject golden_twice "twice_golden\.txt:2: point 0 is listed twice" "$door" "${fast[@]}" \
  --golden "$tmpdir/twice_golden.txt"
reject write_golden_unwritable "/proc/nope/golden\.txt: cannot write the golden file: " \
  "$door" "${fast[@]}" --write-golden /proc/nope/golden.txt

# --- --help: the default output folder ------------------------------------------------
"$UBAKE" regress --help >"$tmpdir/help.txt" 2>&1 || fail "--help: exit status $?"
grep -q -- "--threads N" "$tmpdir/help.txt" || fail "--help does not list --threads"
grep -q "default: regress_NAME in the current" "$tmpdir/help.txt" ||
  fail "--help does not give the default output folder"

# --- full runs: the default folder, --threads, --write-golden then --golden ------------
mkdir -p "$tmpdir/run"
(cd "$tmpdir/run" && "$UBAKE" regress "$door" "${fast[@]}" --write-golden g.txt \
  >stdout 2>stderr) || fail "write-golden run: exit status $?: $(cat "$tmpdir/run/stderr")"
grep -q "reference 16 spp, 1 thread;" "$tmpdir/run/stdout" ||
  fail "write-golden run: header: $(head -1 "$tmpdir/run/stdout")"
report="$tmpdir/run/regress_door_small/door_small.report.json"
grep -q '"threads": 1,' "$report" 2>/dev/null ||
  fail "--threads 1 did not reach the bake (or no $report)"
rows=$(grep -c '^[0-9]' "$tmpdir/run/g.txt" 2>/dev/null)
[ "${rows:-0}" -ge 4 ] || fail "write-golden run: ${rows:-0} golden rows"
[ -e "$tmpdir/run/g.txt.tmp" ] && fail "write-golden run: g.txt.tmp left behind"
(cd "$tmpdir/run" && "$UBAKE" regress "$door" "${fast[@]}" -o again --golden g.txt \
  >stdout2 2>stderr2) || fail "golden run: exit status $?: $(cat "$tmpdir/run/stderr2")"
grep -q "point(s) within their golden errors" "$tmpdir/run/stdout2" ||
  fail "golden run: no pass line"
echo "golden: $rows points written and checked"
# A golden file listing a point the level does not give: not a pass.
{ cat "$tmpdir/run/g.txt"; echo "250 0.001 0.001"; } >"$tmpdir/run/g_extra.txt"
(cd "$tmpdir/run" && "$UBAKE" regress "$door" "${fast[@]}" -o extra --golden g_extra.txt \
  >stdout4 2>stderr4)
status=$?
[ "$status" -eq 1 ] || fail "extra golden point: exit status $status, expected 1"
grep -q "g_extra.txt: golden point 250 was not measured" "$tmpdir/run/stderr4" ||
  fail "extra golden point: $(cat "$tmpdir/run/stderr4")"

# A golden file that cannot be put in place at the end (the path is a folder): exit 1,
# the path named, no PATH.tmp left, the folder untouched.
mkdir -p "$tmpdir/run/gdir"
(cd "$tmpdir/run" && "$UBAKE" regress "$box" "${fast[@]}" -o box --write-golden gdir \
  >stdout3 2>stderr3)
status=$?
[ "$status" -eq 1 ] || fail "rename failure: exit status $status, expected 1"
one_line rename_failure "$tmpdir/run/stderr3"
grep -q "gdir: cannot write the golden file: " "$tmpdir/run/stderr3" ||
  fail "rename failure: $(cat "$tmpdir/run/stderr3")"
[ -e "$tmpdir/run/gdir.tmp" ] && fail "rename failure: gdir.tmp left behind"
[ -d "$tmpdir/run/gdir" ] || fail "rename failure: the folder was replaced"
echo "rename_failure: status $status: $(head -c 200 "$tmpdir/run/stderr3")"

# --- ubake reference: points beyond the loader's coordinate limit (1e7 m) --------------
ref() {
  local name="$1" want="$2" at="$3" status
  "$UBAKE" reference "$box" --at "$at" --normal 0,1,0 --threads 1 --spp 64 \
    >"$tmpdir/$name.out" 2>"$tmpdir/$name.err"
  status=$?
  [ "$status" -eq "$want" ] || fail "$name: exit status $status, expected $want: $(cat "$tmpdir/$name.err")"
  echo "$name: status $status: $(head -c 200 "$tmpdir/$name.err")"
}
ref far_2e18 1 2e18,0,0
one_line far_2e18 "$tmpdir/far_2e18.err"
grep -qF -- "--at takes X,Y,Z, each within +-1e7 m" "$tmpdir/far_2e18.err" ||
  fail "far_2e18: the message does not name the option and the limit"
# (the library's own check, reached by callers other than the CLI: test_reference)
ref far_1e18 1 0,-1e18,0
ref far_2e7 1 0,0,2e7
ref at_limit 0 -1e7,1,0

finish "all regress CLI checks passed"
