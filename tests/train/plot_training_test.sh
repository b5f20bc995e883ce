#!/usr/bin/env bash
# scripts/plot-training on a small log: a valid PNG of the fixed size, one printed line per
# curve with its smoothed end value, skipped and non-finite steps left out, and a clear error
# (exit 1) for a line that is not JSON.
set -euo pipefail
script="$1"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
log="$work/train.jsonl"
for s in 0 1 2 3; do
  echo "{\"step\": $s, \"loss\": $((4 - s)).0, \"terms\": {\"canonical\": 0.5, \"tv\": 0.01}, \"skipped\": false}" >>"$log"
done
echo '{"step": 4, "loss": null, "terms": {}, "skipped": true}' >>"$log"
out="$("$script" "$log" "$work/curve.png" --smooth 1)"
echo "$out"
grep -q "^loss: colour rgb(20, 20, 20), steps 0..3, smoothed 4 -> 1$" <<<"$out"
grep -q "^canonical: .*smoothed 0.5 -> 0.5$" <<<"$out"
grep -q "^tv: " <<<"$out"
# PNG signature and the IHDR size 900 x 450.
[ "$(head -c 8 "$work/curve.png" | od -An -tx1 | tr -d ' \n')" = "89504e470d0a1a0a" ]
[ "$(dd if="$work/curve.png" bs=1 skip=16 count=8 2>/dev/null | od -An -tx1 | tr -d ' \n')" = "00000384000001c2" ]
echo 'not json' >>"$log"
if "$script" "$log" "$work/bad.png" 2>"$work/err"; then
  echo "a broken log was accepted" >&2
  exit 1
fi
grep -q "train.jsonl:6: not JSON" "$work/err"
[ ! -e "$work/bad.png" ]
echo "plot-training: ok"
