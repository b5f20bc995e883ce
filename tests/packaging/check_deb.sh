#!/usr/bin/env bash
# Builds the Debian package with CPack from the build tree and checks it the way a user and
# Debian would:
#  - its files: the binary, desktop entry, icon, AppStream data, manual page, copyright and
#    changelog, the bundled models, and under /usr/share/avatar-studio exactly the files that
#    packaging/data-packages.tsv marks "deb" (nothing that only scripts/setup installs);
#  - its Depends line (OpenBLAS) and Recommends (ffmpeg);
#  - lintian (no errors; every warning listed with its reason in docs/PACKAGING.md),
#    appstreamcli validate and desktop-file-validate on the installed files (output in the log);
#  - acceptance: unpacked into a scratch root and run from there with an empty HOME, no
#    AVATAR_DATA_DIR and no data folder, `analyze` finds the face of the packaged photo, and
#    `reconstruct` + `render` produce a frame with the bundled neural model.
# Needs a full build (build/app/avatar-studio) and the data folder of scripts/setup, which the
# package takes its face networks from; lintian, appstreamcli and desktop-file-validate come
# from scripts/setup's Debian packages.
set -uo pipefail
build_dir="$1"
repo="$2"
list="$repo/packaging/data-packages.tsv"
status=0
fail() { echo "FAIL: $*"; status=1; }
for tool in cpack dpkg-deb lintian appstreamcli desktop-file-validate; do
  command -v "$tool" >/dev/null ||
    { echo "FAIL: $tool is missing; scripts/setup installs it (Debian packages lintian, appstream, desktop-file-utils)"; exit 1; }
done
[ -x "$build_dir/app/avatar-studio" ] || { echo "FAIL: $build_dir/app/avatar-studio is not built; build it first"; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

start=$(date +%s)
(cd "$build_dir" && cpack -G DEB -B "$work" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; echo "FAIL: cpack"; exit 1; }
deb=$(find "$work" -maxdepth 1 -name '*.deb' | head -n 1)
echo "built $(basename "$deb") ($(du -h "$deb" | cut -f1)) in $(($(date +%s) - start)) s"
dpkg-deb -c "$deb" | awk '{print $NF}' | grep -v '/$' | sed 's|^\./||' | sort >"$work/files.txt"
dpkg-deb -f "$deb" Package Version Installed-Size Depends Recommends

# Files.
for want in usr/bin/avatar-studio usr/share/applications/avatar-studio.desktop \
            usr/share/icons/hicolor/scalable/apps/avatar-studio.svg \
            usr/share/metainfo/io.github.avatarstudio.AvatarStudio.metainfo.xml \
            usr/share/man/man1/avatar-studio.1.gz usr/share/doc/avatar-studio/copyright \
            usr/share/doc/avatar-studio/changelog.gz; do
  grep -qx "$want" "$work/files.txt" || fail "the package lacks /$want"
done
# Under share/avatar-studio: the project's models plus exactly the list's "deb" files.
expected=(models/goha-default.ckpt models/fusion-default.ckpt morphable/face_model.avmm morphable/PROVENANCE.txt)
while IFS=$'\t' read -r kind _ _ member dest ship; do
  { [ "$kind" = file ] && [ "$ship" = deb ]; } || continue
  if [[ "$dest" == */ ]]; then expected+=("$dest${member##*/}"); else expected+=("$dest"); fi
done < <(grep -v '^#' "$list")
shipped=$(grep '^usr/share/avatar-studio/' "$work/files.txt" | sed 's|^usr/share/avatar-studio/||')
for pattern in "${expected[@]}"; do
  found=0
  # shellcheck disable=SC2053  # the list may use a glob
  while IFS= read -r f; do [[ "$f" == $pattern ]] && found=1; done <<<"$shipped"
  [ $found -eq 1 ] || fail "the package lacks /usr/share/avatar-studio/$pattern (data-packages.tsv ships it)"
done
while IFS= read -r f; do
  known=0
  # shellcheck disable=SC2053
  for pattern in "${expected[@]}"; do [[ "$f" == $pattern ]] && known=1; done
  [ $known -eq 1 ] || fail "the package carries /usr/share/avatar-studio/$f, which data-packages.tsv does not mark deb"
done <<<"$shipped"
echo "/usr/share/avatar-studio holds $(wc -l <<<"$shipped") files: the 4 of the project and the $((${#expected[@]} - 4)) that data-packages.tsv ships"

# Dependencies.
depends=$(dpkg-deb -f "$deb" Depends)
grep -q "libopenblas0-openmp | libopenblas0-pthread" <<<"$depends" || fail "Depends lacks OpenBLAS: $depends"
grep -q "libtorch" <<<"$depends" || fail "Depends lacks LibTorch (dpkg-shlibdeps): $depends"
[ "$(dpkg-deb -f "$deb" Recommends)" = ffmpeg ] || fail "Recommends is not ffmpeg"

# Debian's checks.
echo "--- lintian $(lintian --version | cut -d' ' -f2)"
lintian --tag-display-limit 0 -I "$deb" 2>&1 | grep -v "^N: \|running with root privileges" | tee "$work/lintian.txt"
grep -q "^E: " "$work/lintian.txt" && fail "lintian reports errors (E: lines above)"
while read -r tag; do
  grep -q "\`$tag\`" "$repo/docs/PACKAGING.md" || fail "lintian warning $tag is not explained in docs/PACKAGING.md"
done < <(grep "^W: " "$work/lintian.txt" | awk '{print $3}' | sort -u)
mkdir -p "$work/root" && dpkg-deb -x "$deb" "$work/root"
echo "--- appstreamcli validate"
appstreamcli validate --no-net "$work/root/usr/share/metainfo/io.github.avatarstudio.AvatarStudio.metainfo.xml" ||
  fail "appstreamcli validate"
echo "--- desktop-file-validate"
if desktop-file-validate "$work/root/usr/share/applications/avatar-studio.desktop"; then echo "desktop entry valid"
else fail "desktop-file-validate"; fi

# Acceptance: the unpacked package on its own.
home="$work/home"
mkdir -p "$home"
installed() {
  env -i HOME="$home" PATH=/usr/bin:/bin LANG=C.UTF-8 AVATAR_THREADS=1 OMP_WAIT_POLICY=PASSIVE \
    "$work/root/usr/bin/avatar-studio" "$@"
}
share="$work/root/usr/share/avatar-studio"
echo "--- the installed binary, HOME=$home (empty), no AVATAR_DATA_DIR"
installed --version | tee "$work/version.txt"
grep -q "default model: $share/models/goha-default.ckpt (bundled)" "$work/version.txt" ||
  fail "the installed binary does not use the packaged model"
grep -q "detail finish: $share/models/fusion-default.ckpt (bundled)" "$work/version.txt" ||
  fail "the installed binary does not use the packaged fusion net"
if installed analyze "$share/samples/grace_hopper.jpg" --json >"$work/analyze.json" 2>"$work/analyze.err"; then
  faces=$(grep -o '"box"' "$work/analyze.json" | wc -l)
  echo "analyze: $faces face(s) in the packaged photo, identity embedding by" \
    "$(grep -o '"embedding_model":"[^"]*"' "$work/analyze.json" | cut -d'"' -f4)"
  [ "$faces" -ge 1 ] || fail "analyze found no face in the packaged photo"
  grep -q '"embedding_model":"fr_feature.onnx"' "$work/analyze.json" || fail "analyze did not use the packaged identity network"
else
  cat "$work/analyze.err"; fail "analyze failed with the packaged data"
  # Tell a package that lacks files from a program that does not look in it.
  if AVATAR_DATA_DIR="$share" "$work/root/usr/bin/avatar-studio" analyze "$share/samples/grace_hopper.jpg" >/dev/null 2>&1; then
    echo "(with AVATAR_DATA_DIR=$share analyze works: the package has the data, the program did not look for it there)"
  fi
fi
if installed reconstruct "$share/samples/grace_hopper.jpg" -o "$work/grace.avatar" >"$work/rec.txt" 2>&1; then
  tail -n 1 "$work/rec.txt"
  grep -q "bundled neural model" "$work/rec.txt" || fail "reconstruct did not use the bundled neural model"
else
  cat "$work/rec.txt"; fail "reconstruct failed with the packaged data"
fi
if installed render "$work/grace.avatar" --yaw 20 -o "$work/frame.png" >"$work/render.txt" 2>&1; then
  cat "$work/render.txt"
  grep -q "bundled neural model" "$work/render.txt" || fail "render did not use the bundled neural model"
  grep -q "finished by the fusion net" "$work/render.txt" || fail "render did not finish the frame with the fusion net"
  file "$work/frame.png" | grep -q "PNG image data" || fail "render wrote no PNG"
  bytes=$(stat -c %s "$work/frame.png")
  echo "frame: $(file -b "$work/frame.png" | cut -d, -f2), $bytes bytes"
  # A flat or empty frame compresses to a few kB; the soft neural head does not.
  [ "$bytes" -ge 10000 ] || fail "the rendered frame is nearly empty ($bytes bytes)"
else
  cat "$work/render.txt"; fail "render failed with the packaged data"
fi
[ ! -e "$home/.cache/avatar-studio/models" ] || fail "the installed binary wrote a data folder into HOME"
echo "checked in $(($(date +%s) - start)) s"
[ $status -eq 0 ] && echo "OK"
exit $status
