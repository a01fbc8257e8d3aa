# tests/cli_lib.sh — sourced by the CLI shell tests (tests/test_*_cli.sh, test_cli_args.sh)
# as `. "$(dirname "$0")/cli_lib.sh" NAME`: strict mode; UBAKE (the ubake program) and
# build (UB_BUILD, the build tree with its levels/) from CTest's environment; tmpdir, a
# temporary folder named after NAME and removed on exit; fail MESSAGE counting failures;
# finish MESSAGE ending the test: exit 1 after any failure, else MESSAGE on stdout.
set -u

: "${UBAKE:?UBAKE must point to the ubake program}"
build="${UB_BUILD:?UB_BUILD must point to the build tree}"
tmpdir="$(mktemp -d "${TMPDIR:-/tmp}/ubake_${1:-cli}.XXXXXX")"
trap 'rm -rf "$tmpdir"' EXIT

failures=0
fail() {
  echo "FAIL: $*" >&2
  failures=$((failures + 1))
}

finish() {
  if [ "$failures" -ne 0 ]; then
    echo "$failures failure(s)" >&2
    exit 1
  fi
  echo "$1"
}
