#!/usr/bin/env bash
# Proves that avatar_neural (core/model, core/render, core/train and the util/io sources they use)
# builds with LibTorch and header-only libraries alone:
#  1. its compile commands (compile_commands.json) name no OpenCV and no Qt include path;
#  2. none of its sources, nor any project header they include (followed recursively), includes
#     an OpenCV or Qt header;
#  3. the executable linked against avatar_neural alone (every object of it) has no OpenCV or Qt
#     library among its direct dependencies.
# The linker keeps only the libraries an executable uses (--as-needed), so (3) counts because the
# executable takes every object of avatar_neural: a use of OpenCV there would show (or fail the link).
# Debian's libtorch_cpu itself loads OpenCV (and through it Qt 5) at run time; that is the
# distribution's LibTorch build, not a dependency of our code, so only direct links count.
# Usage: neural_has_no_opencv.sh SOURCE_ROOT COMPILE_COMMANDS_JSON EXECUTABLE SOURCE...
set -euo pipefail
root="$1"
commands="$2"
exe="$3"
shift 3
fail=0

# 1. Compile lines of the library's own sources.
sources=()
for s in "$@"; do
  case "$s" in *.cc) sources+=("$s") ;; esac
done
if [ "${#sources[@]}" -eq 0 ]; then
  echo "FAIL: no .cc sources of avatar_neural were given"
  exit 1
fi
# A source compiles alone (OBJ_DIR/.../NAME.cc.o) or inside a unity batch (OBJ_DIR/Unity/unity_N_cxx.cxx,
# which includes it by path; AVATAR_UNITY_BUILD); every source must be in one of the two.
lines=$(grep '"command":' "$commands" | grep -E -- '-o [^ ]*avatar_neural\.dir/[^ ]*\.(cc|cxx)\.o' || true)
obj_dir=$(printf '%s\n' "$lines" | grep -oE -- '-o [^ ]*avatar_neural\.dir/' | head -n 1 | sed 's/^-o //')
build_dir=$(dirname "$commands")
unity_files=()
if [ -n "$obj_dir" ] && [ -d "$build_dir/$obj_dir/Unity" ]; then
  mapfile -t unity_files < <(find "$build_dir/$obj_dir/Unity" -name 'unity_*_cxx.cxx')
fi
for s in "${sources[@]}"; do
  if ! printf '%s\n' "$lines" | grep -qF -- "$(basename "$s").o" &&
    { [ "${#unity_files[@]}" -eq 0 ] || ! grep -qF -- "\"$s\"" "${unity_files[@]}"; }; then
    echo "FAIL: $commands compiles no object of avatar_neural's $s, alone or in a unity batch (regenerate the build)"
    fail=1
  fi
done
if printf '%s\n' "$lines" | grep -iE 'opencv|qt[56]|/qt'; then
  echo "FAIL: the compile commands above give avatar_neural an OpenCV or Qt include path"
  fail=1
fi

# 2. Includes of the sources and, recursively, of the project headers they include.
declare -A seen=()
queue=("${sources[@]}")
for s in "${sources[@]}"; do
  h="${s%.cc}.h"
  [ -f "$h" ] && queue+=("$h")
done
while [ "${#queue[@]}" -gt 0 ]; do
  f="${queue[0]}"
  queue=("${queue[@]:1}")
  [ -n "${seen[$f]:-}" ] && continue
  seen[$f]=1
  if grep -nE '#\s*include\s*[<"](opencv|Q[A-Za-z]|qt)' "$f"; then
    echo "FAIL: $f includes the OpenCV or Qt header(s) above"
    fail=1
  fi
  while IFS= read -r inc; do
    [ -f "$root/$inc" ] && queue+=("$root/$inc")
  done < <(grep -oE '#\s*include\s*"[^"]+"' "$f" | sed -E 's/.*"([^"]+)"/\1/')
done

# 3. Direct library dependencies of the executable linked against avatar_neural alone.
if readelf -d "$exe" | grep NEEDED | grep -iE 'opencv|qt'; then
  echo "FAIL: $exe links the OpenCV or Qt libraries above directly"
  fail=1
fi
[ "$fail" -eq 0 ] || exit 1
echo "OK: ${#sources[@]} avatar_neural sources and ${#seen[@]} files they include (with their headers) include" \
     "no OpenCV or Qt header; their $(printf '%s\n' "$lines" | grep -c .) compile commands (${#unity_files[@]} unity" \
     "batches) have no OpenCV or Qt include path;" \
     "$(basename "$exe") links $(readelf -d "$exe" | grep -c NEEDED) libraries directly, none of them OpenCV or Qt"
