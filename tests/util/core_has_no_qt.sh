#!/usr/bin/env bash
# Proves that avatar_core does not depend on Qt:
#  1. no source under core/ includes a Qt header;
#  2. the core-only test executable (linked against avatar_core alone) has no Qt library
#     among its direct dependencies;
#  3. nothing it loads, even indirectly, is Qt 6 (the Qt our ui/ uses).
# Note: Debian's libtorch_cpu itself needs libopencv_highgui, which needs Qt 5; that is a
# property of the distribution's LibTorch build, not of our code, and this script reports it.
set -euo pipefail
core_dir="$1"
exe="$2"
if grep -rnE '#\s*include\s*[<"](Q[A-Z]|qt)' "$core_dir"; then
  echo "FAIL: the lines above include Qt headers inside core/"
  exit 1
fi
if readelf -d "$exe" | grep NEEDED | grep -i 'qt'; then
  echo "FAIL: $exe links Qt directly, so avatar_core depends on Qt"
  exit 1
fi
if ldd "$exe" | grep -i 'libqt6'; then
  echo "FAIL: $exe loads Qt 6 indirectly"
  exit 1
fi
count=$(find "$core_dir" -name '*.cc' | wc -l)
echo "OK: $count core sources include no Qt header; $(basename "$exe") links no Qt library and loads no Qt 6"
if ldd "$exe" | grep -qi 'libqt5'; then
  echo "note: Qt 5 is loaded only through Debian's libtorch_cpu -> libopencv_highgui (not a dependency of our code)"
fi
