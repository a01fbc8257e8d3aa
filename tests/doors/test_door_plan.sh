# tests/doors/test_door_plan.sh — the plan runs a door pass per door and none without doors:
# - two_rooms (no door): the plan says "no door pass", the report has "doors": 0,
#   "door_passes": 0 and no [doors] stage runs;
# - sunroom (door "front"): the plan lists "pass door front" (plan only, nothing baked);
# - door_combo: ubake_combine names listed (a set as a candidate; the door itself and an
#   unknown name as skipped, with the reason); none without the tag; door_chain: a
#   door x door candidate.
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

# door_combo: the door's ubake_combine tag names the set lamp_b (a candidate), the door
# itself and an unknown name (both listed as skipped, with the reason); combine=0: no
# combination line. door_chain: door bc x door ab is a candidate.
"$build/ubake-genlevel" door_combo -o "$tmp" --name combo_tags >/dev/null || fail "genlevel door_combo"
sed -i 's/"ubake_combine":"lamp_b"/"ubake_combine":"lamp_b, middle,nosuch"/; s/"ubake_combine": "lamp_b"/"ubake_combine": "lamp_b, middle,nosuch"/' \
  "$tmp/combo_tags.gltf"
grep -q 'lamp_b, middle,nosuch' "$tmp/combo_tags.gltf" || fail "could not retag combo_tags.gltf"
out="$("$UBAKE" bake "$tmp/combo_tags.gltf" --plan-only 2>&1)" || fail "door_combo --plan-only failed"
echo "$out" | grep -q "combination door middle x lamp_b: tagged" || fail "no lamp_b combination candidate"
echo "$out" | grep -q "combination door middle x middle: skipped: a door with itself" \
  || fail "the door itself not listed as skipped"
echo "$out" | grep -q "combination door middle x nosuch: skipped: nosuch is not" \
  || fail "unknown name not listed as skipped"
"$build/ubake-genlevel" door_combo -o "$tmp" --name combo_none --param combine=0 >/dev/null \
  || fail "genlevel door_combo combine=0"
out="$("$UBAKE" bake "$tmp/combo_none.gltf" --plan-only 2>&1)" || fail "combo_none --plan-only failed"
echo "$out" | grep -q "combination" && fail "untagged door lists a combination"

"$build/ubake-genlevel" door_chain -o "$tmp" >/dev/null || fail "genlevel door_chain"
out="$("$UBAKE" bake "$tmp/door_chain.gltf" --plan-only 2>&1)" || fail "door_chain --plan-only failed"
echo "$out" | grep -q "combination door bc x ab: tagged" || fail "no door x door candidate"

[ "$failures" -eq 0 ] && echo "door plan: ok"
exit $((failures > 0))
