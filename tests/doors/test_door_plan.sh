# tests/doors/test_door_plan.sh — the plan runs a door pass per door and none without doors:
# - two_rooms (no door): the plan says "no door pass", the report has "doors": 0,
#   "door_passes": 0 and no [doors] stage runs;
# - sunroom (door "front"): the plan lists "pass door front" (plan only, nothing baked).
# Env (set by CTest): UBAKE = the ubake program, UB_BUILD = build tree.
set -u
: "${UBAKE:?UBAKE must point to the ubake program}"
build="${UB_BUILD:?UB_BUILD must point to the build tree}"
tmp="$(mktemp -d "${TMPDIR:-/tmp}/ubake_door_plan.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
failures=0
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }

out="$("$UBAKE" bake "$build/levels/two_rooms.gltf" -o "$tmp/tr" --quality draft --no-progress 2>&1)" \
  || fail "two_rooms bake failed"
echo "$out" | grep -q "doors: 0, no door pass" || fail "two_rooms plan does not say 'no door pass'"
echo "$out" | grep -q "\[doors" && fail "two_rooms ran a door stage"
grep -q '"doors": 0, "door_passes": 0' "$tmp/tr/two_rooms.report.json" \
  || fail "two_rooms report: doors/door_passes not 0"
grep -q '"dls_passes": 0, "door_passes": 0' "$tmp/tr/two_rooms.report.json" \
  || fail "two_rooms report: effect counter door_passes not 0"

out="$("$UBAKE" bake "$build/levels/sunroom.gltf" --plan-only 2>&1)" || fail "sunroom --plan-only failed"
echo "$out" | grep -q "pass door front:" || fail "sunroom plan has no door pass"

[ "$failures" -eq 0 ] && echo "door plan: ok"
exit $((failures > 0))
