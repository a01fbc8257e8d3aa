# tests/test_bad_input.sh — `ubake bake` on bad levels: exit status 1, one stderr line
# naming the file, and nothing written to the output directory.
# Env (set by CTest): UBAKE = the ubake program, UB_SOURCE = source tree.
set -u

: "${UBAKE:?UBAKE must point to the ubake program}"
src="${UB_SOURCE:-$(cd "$(dirname "$0")/.." && pwd)}"
bad="$src/tests/data/bad"
tmpdir="$(mktemp -d "${TMPDIR:-/tmp}/ubake_bad_input.XXXXXX")"
trap 'rm -rf "$tmpdir"' EXIT

failures=0
fail() {
  echo "FAIL: $*" >&2
  failures=$((failures + 1))
}

check() {
  local file="$1" name out status lines
  name="$(basename "$file")"
  out="$tmpdir/out"
  rm -rf "$out"
  "$UBAKE" bake "$file" -o "$out" >"$tmpdir/stdout" 2>"$tmpdir/stderr"
  status=$?
  lines=$(wc -l <"$tmpdir/stderr")
  [ "$status" -eq 1 ] || fail "$name: exit status $status, expected 1"
  # one line: a single newline-terminated line (or one unterminated line)
  if ! { [ "$lines" -eq 1 ] || { [ "$lines" -eq 0 ] && [ -s "$tmpdir/stderr" ]; }; }; then
    fail "$name: stderr has $lines lines, expected 1:"
    sed 's/^/    /' "$tmpdir/stderr" >&2
  fi
  grep -qF "$name" "$tmpdir/stderr" || fail "$name: stderr does not name the file: $(cat "$tmpdir/stderr")"
  if [ -e "$out" ] && [ -n "$(find "$out" -mindepth 1 -print -quit)" ]; then
    fail "$name: output directory is not empty:"
    find "$out" -mindepth 1 >&2
  fi
  echo "$name: status $status: $(head -c 300 "$tmpdir/stderr")"
}

count=0
for f in "$bad"/*; do
  [ -f "$f" ] || continue
  check "$f"
  count=$((count + 1))
done
check "$bad/this_level_does_not_exist.gltf"

[ "$count" -ge 8 ] || fail "expected at least 8 bad inputs in $bad, found $count"
if [ "$failures" -ne 0 ]; then
  echo "$failures failure(s)" >&2
  exit 1
fi
echo "all bad inputs rejected"
