# tests/test_bake_output.sh — `ubake bake`'s output folder: a bad -o or --json fails before
# any stage runs, naming the path; a failed, interrupted or killed bake leaves no staging
# folder (nor a folder it made); the report at a --json path on another file system is no
# cross-device rename; a re-bake with fewer atlases removes the old ones; a level name too
# long for the .ubk is refused (it was cut, and two levels wrote the same files); messages
# of the write stage name the final paths.
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = build tree (levels/cornell.gltf,
# levels/hallway.gltf), UB_SOURCE = source tree.
set -u

: "${UBAKE:?UBAKE must point to the ubake program}"
: "${UB_BUILD:?UB_BUILD must point to the build tree}"
tmpdir="$(mktemp -d "${TMPDIR:-/tmp}/ubake_bake_output.XXXXXX")"
shm_json=""
cleanup() {
  rm -rf "$tmpdir"
  [ -n "$shm_json" ] && rm -f "$shm_json" "$(dirname "$shm_json")"/."$(basename "$shm_json")".tmp-*
}
trap cleanup EXIT

failures=0
fail() {
  echo "FAIL: $*" >&2
  failures=$((failures + 1))
}

lv="$tmpdir/lv"
mkdir -p "$lv"
cp "$UB_BUILD/levels/cornell.gltf" "$UB_BUILD/levels/cornell.bin" "$lv/" || exit 1
B=(--quality draft --threads 1 --no-progress)
w="$tmpdir/w"
mkdir -p "$w"

# bake ARGS...: runs ubake bake on them; status in $status, output in $w/stdout, $w/stderr.
bake() {
  "$UBAKE" bake "$@" >"$w/stdout" 2>"$w/stderr"
  status=$?
}

# No hidden staging folder or temporary file anywhere under the given folders.
no_leftovers() {
  local what="$1" left
  shift
  left=$(find "$@" -name '.*.staging-*' -o -name '*.tmp' -o -name '.*.tmp-*' 2>/dev/null)
  [ -z "$left" ] || fail "$what: left behind: $left"
}

# A bad output path: exit 1 before the first stage, one stderr line naming $2.
fails_early() {
  local what="$1" name="$2"
  shift 2
  bake "$@"
  [ "$status" -eq 1 ] || fail "$what: exit status $status, expected 1"
  grep -q '^\[' "$w/stdout" && fail "$what: stages ran before the error: $(grep '^\[' "$w/stdout" | head -2 | tr '\n' ' ')"
  [ "$(wc -l <"$w/stderr")" -eq 1 ] || fail "$what: stderr is not one line: $(cat "$w/stderr")"
  grep -qF -- "$name" "$w/stderr" || fail "$what: stderr does not name $name: $(cat "$w/stderr")"
  grep -q 'staging' "$w/stderr" && fail "$what: the message names the staging folder: $(cat "$w/stderr")"
  echo "$what: status $status: $(head -c 200 "$w/stderr")"
}

# --- 1. the report at a --json path ---------------------------------------------------
# On another file system (/dev/shm is a tmpfs): it was renamed from the staging folder
# (EXDEV) after the bake's other files were already in place.
if [ -d /dev/shm ] && [ -w /dev/shm ] && [ "$(stat -c %d /dev/shm)" != "$(stat -c %d "$tmpdir")" ]; then
  shm_json="/dev/shm/ubake_bake_output_$$.json"
  bake "$lv/cornell.gltf" -o "$w/jx" --json "$shm_json" "${B[@]}"
  [ "$status" -eq 0 ] || fail "--json on /dev/shm: exit status $status: $(cat "$w/stderr")"
  [ -s "$shm_json" ] || fail "--json on /dev/shm: no report at $shm_json"
  [ -e "$w/jx/cornell.report.json" ] && fail "--json on /dev/shm: a report in DIR as well"
  no_leftovers "--json on /dev/shm" "$w/jx" /dev/shm
  echo "--json on /dev/shm: status $status"
else
  echo "--json on another file system: skipped (no /dev/shm on another device)"
fi
# Into a folder that does not exist: refused at the start; an earlier bake in DIR stays
# untouched (it got the new .ubk and atlases next to the old report).
bake "$lv/cornell.gltf" -o "$w/j2" "${B[@]}"
[ "$status" -eq 0 ] || fail "bake into j2: exit status $status: $(cat "$w/stderr")"
before=$(cd "$w/j2" && ls -Ail --time-style=full-iso)
fails_early "--json into a missing folder" "$w/nodir/r.json" "$lv/cornell.gltf" -o "$w/j2" --json "$w/nodir/r.json" "${B[@]}"
[ "$before" = "$(cd "$w/j2" && ls -Ail --time-style=full-iso)" ] ||
  fail "--json into a missing folder: the earlier bake in DIR changed"
fails_early "--json naming a folder" "$w/j2" "$lv/cornell.gltf" -o "$w/j3" --json "$w/j2" "${B[@]}"
[ -e "$w/j3" ] && fail "--json naming a folder: the output folder it made is left: $(ls -a "$w/j3")"
# Onto one of the bake's own files (the .ubk, an atlas, by another spelling of DIR): refused
# at the start, the earlier bake in DIR untouched.
fails_early "--json onto the .ubk" "$w/j2/cornell.ubk" "$lv/cornell.gltf" -o "$w/j2" \
  --json "$w/j2/cornell.ubk" "${B[@]}"
fails_early "--json onto an atlas" "$w/j2/../j2/cornell_lm0.png" "$lv/cornell.gltf" -o "$w/j2" \
  --json "$w/j2/../j2/cornell_lm0.png" "${B[@]}"
[ "$before" = "$(cd "$w/j2" && ls -Ail --time-style=full-iso)" ] ||
  fail "--json onto the bake's own files: the earlier bake in DIR changed"
# Into another folder of the same file system: there, and nothing else left.
mkdir -p "$w/jr"
bake "$lv/cornell.gltf" -o "$w/j4" --json "$w/jr/r.json" "${B[@]}"
[ "$status" -eq 0 ] && [ -s "$w/jr/r.json" ] || fail "--json into another folder: status $status, report $(ls -a "$w/jr")"
[ "$(ls -A "$w/jr")" = "r.json" ] || fail "--json into another folder: $(ls -A "$w/jr")"
no_leftovers "--json into another folder" "$w/j4" "$w/jr"

# --- 2. a bad output folder fails at once, naming the -o value --------------------------
echo "not a folder" >"$w/afile"
fails_early "-o an existing file" "$w/afile" "$lv/cornell.gltf" -o "$w/afile" "${B[@]}"
fails_early "-o under a file" "$w/afile/sub" "$lv/cornell.gltf" -o "$w/afile/sub" "${B[@]}"
[ "$(cat "$w/afile")" = "not a folder" ] || fail "-o under a file: the file changed"
fails_early "-o \"\"" '""' "$lv/cornell.gltf" -o "" "${B[@]}"
if [ -d /proc/self ]; then
  fails_early "-o /proc/foo" "/proc/foo" "$lv/cornell.gltf" -o /proc/foo "${B[@]}"
fi
# A folder the bake cannot write into (root ignores permissions: then /sys, if there).
if [ "$(id -u)" -ne 0 ]; then
  mkdir -p "$w/ro" && chmod 555 "$w/ro"
  fails_early "-o a read-only folder" "$w/ro" "$lv/cornell.gltf" -o "$w/ro" "${B[@]}"
  chmod 755 "$w/ro"
elif [ -d /sys/kernel ]; then
  if mkdir /sys/ubake_probe_$$ 2>/dev/null; then
    rmdir /sys/ubake_probe_$$
  else
    fails_early "-o a folder no one may write into" "/sys" "$lv/cornell.gltf" -o /sys "${B[@]}"
  fi
fi
# A bake that fails in its first stage leaves neither the staging folder nor the folders
# it made; one that fails in its last (a folder where the .ubk goes) moves nothing into
# place and leaves no staging folder.
printf '{"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"mesh":7}]}' >"$lv/bad.gltf"
bake "$lv/bad.gltf" -o "$w/made/deep/out" "${B[@]}"
[ "$status" -eq 1 ] || fail "bad level: exit status $status, expected 1"
[ -e "$w/made" ] && fail "bad level: the folders it made are left: $(find "$w/made")"
mkdir -p "$w/inway/cornell.ubk"
bake "$lv/cornell.gltf" -o "$w/inway" "${B[@]}"
[ "$status" -eq 1 ] || fail "folder in the way: exit status $status, expected 1"
grep -qF "$w/inway/cornell.ubk" "$w/stderr" || fail "folder in the way: stderr: $(cat "$w/stderr")"
[ "$(ls -A "$w/inway")" = "cornell.ubk" ] || fail "folder in the way: files moved into place: $(ls -A "$w/inway")"
no_leftovers "folder in the way" "$w/inway"
echo "folder in the way: status $status: $(head -c 200 "$w/stderr")"

# --- 3a. SIGINT / SIGTERM: no staging folder left ---------------------------------------
# Job control: a background job of a script would otherwise ignore SIGINT.
set -m
# killed_run SIG WHEN OUT: a bake with a large atlas (about 0.3 s in its write stage) into
# OUT, sent SIG at WHEN: "write" = once the staging folder holds a file, else seconds.
killed_run() {
  local sig="$1" when="$2" out="$3" pid i seen=0
  "$UBAKE" bake "$lv/cornell.gltf" -o "$out" --texel-size 0.015 --gather-rays 1 --bounces 0 \
    "${B[@]}" >"$w/sig.out" 2>&1 &
  pid=$!
  if [ "$when" = write ]; then
    for i in $(seq 2000); do
      if ls "$out"/.cornell.staging-*/* >/dev/null 2>&1; then seen=1; break; fi
      kill -0 "$pid" 2>/dev/null || break
      sleep 0.005
    done
  else
    sleep "$when"
  fi
  kill "-$sig" "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  status=$?
  in_write=$seen
}
write_kills=0
for run in "INT write" "TERM write" "INT 0.05" "TERM 0.3"; do
  set -- $run
  out="$w/sig_$1_$2/out"
  mkdir -p "$(dirname "$out")"
  killed_run "$1" "$2" "$out" 2>/dev/null
  want=$((128 + $(kill -l "$1")))
  if [ "$status" -eq 0 ]; then
    echo "SIG$1 at $2: the bake ended before the signal (not counted)"
  else
    [ "$status" -eq "$want" ] || fail "SIG$1 at $2: exit status $status, expected $want (killed by the signal)"
    [ "$2" = write ] && [ "$in_write" -eq 1 ] && write_kills=$((write_kills + 1))
    # The bake made OUT: nothing of it may stay (unless the signal came while the files were
    # renamed into place: then they all are, and the bake died after).
    if [ -e "$out/cornell.ubk" ] && [ -e "$out/cornell.report.json" ]; then
      echo "SIG$1 at $2: came while moving into place"
      no_leftovers "SIG$1 at $2" "$out"
    elif [ -e "$out" ]; then
      fail "SIG$1 at $2: left $(find "$out" | tr '\n' ' ')"
    fi
    echo "SIG$1 at $2: status $status, left: $(find "$(dirname "$out")" -mindepth 1 | tr '\n' ' ')"
  fi
done
set +m
[ "$write_kills" -ge 1 ] || fail "no bake was killed in its write stage (machine too fast or slow?)"

# --- 3b. stale staging folders of processes that are gone -------------------------------
sleep 0 &
dead=$!
wait "$dead"
if kill -0 "$dead" 2>/dev/null; then
  echo "stale staging: skipped (PID $dead is in use again)"
else
  st="$w/stale"
  mkdir -p "$st/.cornell.staging-$dead" "$st/.cornell.staging-$$" "$st/.other.staging-$dead" \
    "$w/elsewhere"
  echo partial >"$st/.cornell.staging-$dead/cornell_lm0.exr.tmp"
  echo keep >"$w/elsewhere/keep"
  ln -s "$w/elsewhere" "$st/.cornell.staging-$((dead + 100000))" # not a folder of ours
  bake "$lv/cornell.gltf" -o "$st" "${B[@]}"
  [ "$status" -eq 0 ] || fail "stale staging: exit status $status: $(cat "$w/stderr")"
  [ -e "$st/.cornell.staging-$dead" ] && fail "stale staging: .cornell.staging-$dead (process gone) is left"
  grep -q "staging-$dead" "$w/stdout" || fail "stale staging: no info line names the folder removed"
  [ -d "$st/.cornell.staging-$$" ] || fail "stale staging: removed the folder of a running process ($$)"
  [ -d "$st/.other.staging-$dead" ] || fail "stale staging: removed another level's folder"
  [ -f "$w/elsewhere/keep" ] || fail "stale staging: followed a symbolic link"
  echo "stale staging: $(grep "staging-$dead" "$w/stdout")"
  rm -rf "$st"
fi

# --- 4. a re-bake with fewer atlases ----------------------------------------------------
at="$w/atlases"
mkdir -p "$at"
stale="cornell_lm1.exr cornell_lm1.png cornell_error1.exr cornell_error1.png cornell_lm12.png"
others="cornell_lm01.png cornell_lm1.exr.bak cornell_lm1.jpg other_lm1.exr cornell2_lm1.exr
        cornell_lmx.png cornell_error.png"
for f in $stale $others; do echo old >"$at/$f"; done
bake "$lv/cornell.gltf" -o "$at" "${B[@]}"
[ "$status" -eq 0 ] || fail "re-bake: exit status $status: $(cat "$w/stderr")"
for f in $stale; do [ -e "$at/$f" ] && fail "re-bake: $f of the earlier bake is left"; done
for f in $others; do [ -e "$at/$f" ] || fail "re-bake: removed $f, not the level's atlas file"; done
for f in cornell_lm0.exr cornell_lm0.png cornell_error0.exr cornell_error0.png cornell.ubk; do
  [ "$(head -c 3 "$at/$f")" = old ] && fail "re-bake: $f is the old file"
done
echo "re-bake: $(ls "$at" | tr '\n' ' ')"

# --- 5. level names -----------------------------------------------------------------------
x=$(printf 'x%.0s' $(seq 70))
for v in v2 v3; do cp "$lv/cornell.gltf" "$lv/arena.${v}_$x.gltf"; done
for v in v2 v3; do
  fails_early "name of 79 bytes ($v)" "arena.${v}_$x.gltf" "$lv/arena.${v}_$x.gltf" -o "$w/names" "${B[@]}"
  grep -q 63 "$w/stderr" || fail "name of 79 bytes: the message does not give the limit (63)"
done
[ -e "$w/names" ] && fail "long names: wrote $(ls -A "$w/names")"
y=$(printf 'y%.0s' $(seq 63))
cp "$lv/cornell.gltf" "$lv/$y.gltf"
cp "$lv/cornell.gltf" "$lv/lvl.v2.gltf"
for n in "$y" lvl.v2; do
  bake "$lv/$n.gltf" -o "$w/names" "${B[@]}"
  [ "$status" -eq 0 ] && [ -s "$w/names/$n.ubk" ] && [ -s "$w/names/${n}_lm0.exr" ] ||
    fail "name $n: status $status, files $(ls -A "$w/names" 2>&1)"
done

# --- messages of the write stage name the final paths -----------------------------------
mkdir -p "$lv/hot"
cp "$UB_BUILD/levels/estate_small.bin" "$lv/hot/"
# every lamp at 1e12 W/sr (under UB_SCENE_MAX_INTENSITY): the LLG probes' SH (stored as
# halves without a scale) beyond the half range, a warning naming the .ubk
sed 's/"intensity": *[0-9.e+-]*/"intensity": 1e12/g' "$UB_BUILD/levels/estate_small.gltf" \
  >"$lv/hot/estate_small.gltf"
bake "$lv/hot/estate_small.gltf" -o "$w/hot" "${B[@]}" --bounces 1
[ "$status" -eq 0 ] || fail "hot lamp: exit status $status: $(cat "$w/stderr")"
grep -qF "$w/hot/estate_small.ubk: " "$w/stderr" || fail "hot lamp: no warning naming $w/hot/estate_small.ubk: $(cat "$w/stderr")"
grep -q staging "$w/stderr" && fail "hot lamp: a message names the staging folder: $(grep staging "$w/stderr")"
no_leftovers "all bakes" "$w"

if [ "$failures" -ne 0 ]; then
  echo "$failures failure(s)" >&2
  exit 1
fi
echo "output folder checks passed"
