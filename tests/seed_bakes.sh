# tests/seed_bakes.sh — sourced by the noise tests (test_door_noise.sh, test_dls_noise.sh),
# not a test itself: bake one level with seeds 1, 2 and 3 for `ubake spread`.
#
# bake_seeds LEVEL OUT NAME [BAKE OPTIONS...]: `$UBAKE bake LEVEL -o OUT/seedS --seed S
# --no-progress OPTIONS` for S = 1, 2, 3 (logs in OUT/bakeS.log); sets `files` to the
# three OUT/seedS/NAME.ubk. On a failed bake prints its log's tail and exits 1.
bake_seeds() {
  local level="$1" dir="$2" name="$3" seed
  shift 3
  files=""
  for seed in 1 2 3; do
    if ! "$UBAKE" bake "$level" -o "$dir/seed$seed" "$@" --seed "$seed" --no-progress \
        >"$dir/bake$seed.log" 2>&1; then
      echo "FAIL: bake of $level with seed $seed failed:" >&2
      tail -5 "$dir/bake$seed.log" >&2
      exit 1
    fi
    files="$files $dir/seed$seed/$name.ubk"
  done
}
