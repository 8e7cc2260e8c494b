#!/usr/bin/env bash
# After `cargo test`: the checks that did not run (a missing ../shared/data, a tool a test
# needs), from the skip log the tests append to (tests/common: `skip`). `make test` empties the
# log before the run and prints this after it, so a run that checked less says so.
#   scripts/test_skips.sh clear|report
set -euo pipefail
log=${CARGO_TARGET_DIR:-$(dirname "$0")/../target}/tmp/test-skips.log
case ${1:?clear or report} in
  clear) rm -f "$log" ;;
  report)
    if [ -s "$log" ]; then
      echo "== $(wc -l < "$log") checks skipped (they did not run; see each reason):"
      sort "$log" | sed 's/^/   /'
    else
      echo "== no check skipped"
    fi ;;
esac
