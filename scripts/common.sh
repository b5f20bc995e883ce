# Shared helpers for the scripts in this folder (sourced, not executed).
say() { printf '[avatar-studio] %s\n' "$*"; }
warn() { printf '[avatar-studio] warning: %s\n' "$*" >&2; }
die() { printf '[avatar-studio] error: %s\n' "$*" >&2; exit 1; }

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${AVATAR_BUILD_DIR:-$REPO_ROOT/build}"
# Same resolution order as the app (core/io/data_paths.cc), minus the command-line option.
AVATAR_DATA="${AVATAR_DATA_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/avatar-studio}"
export AVATAR_DATA_DIR="$AVATAR_DATA"

# Configures (once) and builds the project in Release mode with Ninja: the targets given (e.g.
# avatar-studio for the demo: the app and the libraries it links), or everything (tests included).
build_project() {
  if [ ! -f "$BUILD_DIR/build.ninja" ]; then
    say "Configuring in $BUILD_DIR"
    cmake -S "$REPO_ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >"$BUILD_DIR.configure.log" 2>&1 ||
      { cat "$BUILD_DIR.configure.log"; die "CMake configuration failed (log above)"; }
  fi
  local what="everything"
  local targets=()
  if [ $# -gt 0 ]; then
    what="$*"
    for t in "$@"; do targets+=(--target "$t"); done
  fi
  say "Building $what (this takes a while the first time; ccache makes later builds fast)"
  local start
  start=$(date +%s)
  cmake --build "$BUILD_DIR" "${targets[@]}" -- -k 0 || die "the build failed (errors above)"
  say "Build: $(($(date +%s) - start)) s"
}
