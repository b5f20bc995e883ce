#!/usr/bin/env bash
# Regenerates the TF.js golden outputs used by the face tests (ctest fixture face/goldens).
# Usage: scripts/goldens/make_goldens.sh OUT_DIR
# Installs pinned pure-JS TensorFlow.js (4.22.0) into $DATA/node once (npm registry), then runs
# make_goldens.js on the installed models (graph models, and nsfwjs's Keras layers model
# through tfjs-layers). DATA = $AVATAR_DATA_DIR, else the default cache.
set -euo pipefail
out="${1:?usage: make_goldens.sh OUT_DIR}"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
data="${AVATAR_DATA_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/avatar-studio}"
fail() { echo "make_goldens: $*" >&2; exit 1; }
command -v node >/dev/null || fail "node is not installed; run scripts/setup (it installs nodejs and npm)"
[ -f "$data/models/facemesh.json" ] || fail "face models not found in $data/models; run scripts/setup"
version=4.22.0
deps="$data/node"
installed() {  # installed PACKAGE: true when $deps holds PACKAGE at $version
  [ -f "$deps/node_modules/@tensorflow/$1/package.json" ] &&
    grep -q "\"version\": \"$version\"" "$deps/node_modules/@tensorflow/$1/package.json"
}
if ! installed tfjs-converter || ! installed tfjs-layers; then
  command -v npm >/dev/null || fail "npm is not installed; run scripts/setup"
  mkdir -p "$deps"
  npm install --no-save --no-audit --no-fund --loglevel=error --prefix "$deps" \
    "@tensorflow/tfjs-core@$version" "@tensorflow/tfjs-backend-cpu@$version" "@tensorflow/tfjs-converter@$version" \
    "@tensorflow/tfjs-layers@$version" \
    >"$deps/npm.log" 2>&1 || fail "npm install of TensorFlow.js $version failed (see $deps/npm.log); is the npm registry reachable?"
fi
rm -rf "$out"
node "$here/make_goldens.js" --models "$data/models" --out "$out" --deps "$deps" 2>&1 | grep -v -e "^====" -e "tfjs-node" -e "^Hi, looks like" -e "^$" || true
[ -f "$out/manifest.json" ] || fail "make_goldens.js wrote no manifest"
