#!/usr/bin/env bash
# Builds the Debian package with CPack and checks that it installs the binary on PATH,
# the desktop entry, the icon, the AppStream metadata and the bundled models, and that the
# installed binary finds its bundled neural model inside the package.
set -euo pipefail
build_dir="$1"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$build_dir" && cpack -G DEB -B "$work" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; exit 1; }
deb=$(ls "$work"/*.deb | head -n 1)
echo "built $(basename "$deb") ($(du -h "$deb" | cut -f1))"
dpkg-deb -c "$deb" >"$work/files.txt"
status=0
for want in ./usr/bin/avatar-studio ./usr/share/applications/avatar-studio.desktop \
            ./usr/share/icons/hicolor/scalable/apps/avatar-studio.svg \
            ./usr/share/metainfo/io.github.avatarstudio.AvatarStudio.metainfo.xml \
            ./usr/share/avatar-studio/models/goha-default.ckpt \
            ./usr/share/avatar-studio/morphable/face_model.avmm; do
  if grep -q " $want\$" "$work/files.txt"; then echo "contains $want"; else echo "MISSING $want"; status=1; fi
done
dpkg-deb -f "$deb" Package Version Depends Recommends
if dpkg-deb -f "$deb" Depends | grep -q "libopenblas0-openmp"; then echo "Depends names OpenBLAS"; else
  echo "MISSING OpenBLAS in Depends"; status=1; fi
# The packaged binary runs (it was installed into the package tree, not just copied).
mkdir -p "$work/root" && dpkg-deb -x "$deb" "$work/root"
"$work/root/usr/bin/avatar-studio" --version | tee "$work/version.txt"
if grep -q "default model: $work/root/usr/share/avatar-studio/models/goha-default.ckpt (bundled)" "$work/version.txt"; then
  echo "the installed binary uses the packaged model"; else echo "WRONG default model (expected the packaged one)"; status=1; fi
exit $status
