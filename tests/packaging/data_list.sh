#!/usr/bin/env bash
# packaging/data-packages.tsv is the one list of pinned third-party data. Checks that
#  1. the list is well formed and scripts/setup pins nothing of its own (no versions or sha256
#     outside the list, so setup and the package cannot drift apart);
#  2. scripts/setup installs what a list says, keeps a data folder that is up to date as it is,
#     and upgrades an older one by fetching only the newer sources (a made-up two-version list
#     with local tarballs and an unreachable registry: any needless download fails);
#  3. the data folder the tests use (AVATAR_DATA_DIR or ~/.cache/avatar-studio) holds every file
#     of the real list at its place.
# (tests/packaging/check_deb.sh checks that the .deb carries exactly the list's "deb" files.)
set -uo pipefail
repo="$1"
list="$repo/packaging/data-packages.tsv"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
status=0
fail() { echo "FAIL: $*"; status=1; }

# 1. Well formed; setup has no pins of its own.
n=0
while IFS= read -r line; do
  n=$((n + 1))
  case "$line" in "" | "#"*) continue ;; esac
  IFS=$'\t' read -r -a f <<<"$line"
  case "${f[0]}" in
    source)
      [ ${#f[@]} -eq 9 ] || fail "line $n: a source has 9 fields, not ${#f[@]}"
      if [ "${f[1]}" = npm ]; then
        [[ "${f[2]}" =~ ^(@[a-z0-9._-]+/)?[a-z0-9._-]+@[0-9][0-9A-Za-z.+-]*$ ]] || fail "line $n: '${f[2]}' is not name@version"
        [[ "${f[3]}" =~ ^[0-9a-f]{64}$ ]] || fail "line $n: '${f[3]}' is not a sha256"
        [[ "${f[5]}" =~ ^(keep|drop)$ ]] || fail "line $n: TARBALL is keep or drop, not '${f[5]}'"
      fi
      ;;
    file)
      [ ${#f[@]} -eq 6 ] || fail "line $n: a file has 6 fields, not ${#f[@]}"
      [[ "${f[5]}" =~ ^(deb|setup)$ ]] || fail "line $n: SHIP is deb or setup, not '${f[5]}'"
      grep -qP "^source\t[a-z]+\t\Q${f[2]}\E(@[^\t]+)?\t" "$list" || fail "line $n: unknown source '${f[2]}'"
      ;;
    note) ;;
    *) fail "line $n: unknown record '${f[0]}'" ;;
  esac
done <"$list"
echo "list: $(grep -c $'^source\t' "$list") sources, $(grep -c $'^file\t' "$list") files ($(grep -cP '^file\t.*\tdeb$' "$list") in the .deb)"
if grep -nE '[0-9a-f]{64}|[a-z]@[0-9]+\.[0-9]+' "$repo/scripts/setup" "$repo/scripts/common.sh"; then
  fail "scripts/setup or common.sh pins packages of its own (lines above); pins belong in $list"
else
  echo "scripts/setup and common.sh pin no package of their own"
fi

# 2. setup against a made-up list: version 1 has npm package alpha and a "Debian" file, version 2
#    adds beta and one more file of alpha.
mk_tarball() {  # name version files... -> sets sha
  local dir="$work/src/$1"
  rm -rf "$dir" && mkdir -p "$dir/package/sub"
  local f
  for f in "${@:3}"; do echo "$1 $2 $f" >"$dir/package/$f"; done
  tar -czf "$work/tarballs/avatar-test-$1-$2.tgz" -C "$dir" package
  sha=$(sha256sum "$work/tarballs/avatar-test-$1-$2.tgz" | cut -d' ' -f1)
}
mkdir -p "$work/tarballs"
mk_tarball alpha 1.0.0 a1.txt sub/a2.txt sub/a3.txt; sha_alpha=$sha
mk_tarball beta 2.0.0 LICENSE b.bin; sha_beta=$sha
echo "a photo" >"$work/debian-photo.jpg"
tab=$'\t'
{
  echo "# made-up list"
  echo "source${tab}npm${tab}@avatar-test/alpha@1.0.0${tab}$sha_alpha${tab}1${tab}keep${tab}MIT${tab}A${tab}https://a"
  echo "source${tab}debian${tab}fake-debian-package${tab}-${tab}1${tab}-${tab}public-domain${tab}P${tab}https://p"
  echo "source${tab}npm${tab}@avatar-test/beta@2.0.0${tab}$sha_beta${tab}2${tab}drop${tab}MIT${tab}B${tab}https://b"
  echo "file${tab}1${tab}@avatar-test/alpha${tab}package/a1.txt${tab}models/${tab}deb"
  echo "file${tab}1${tab}@avatar-test/alpha${tab}package/sub/a2.*${tab}samples/${tab}setup"
  echo "file${tab}1${tab}fake-debian-package${tab}$work/debian-photo.jpg${tab}samples/${tab}deb"
  echo "file${tab}2${tab}@avatar-test/alpha${tab}package/sub/a3.txt${tab}training/alpha/third.txt${tab}setup"
  echo "file${tab}2${tab}@avatar-test/beta${tab}package/b.bin${tab}models/beta/${tab}deb"
  echo "file${tab}2${tab}@avatar-test/beta${tab}package/LICENSE${tab}models/beta-LICENSE${tab}setup"
  echo "note${tab}2${tab}training/: made-up note"
} >"$work/list.tsv"
data="$work/data"
run_setup() {
  AVATAR_DATA_LIST="$work/list.tsv" AVATAR_DATA_DIR="$data" npm_config_registry=http://127.0.0.1:9/ \
    "$repo/scripts/setup" </dev/null >"$work/setup.log" 2>&1
}
mkdir -p "$data/downloads"
cp "$work"/tarballs/*.tgz "$data/downloads/"
if run_setup; then echo "setup: fresh install from the made-up list"; else cat "$work/setup.log"; fail "setup failed on a fresh folder"; fi
want=(models/a1.txt samples/a2.txt samples/debian-photo.jpg training/alpha/third.txt models/beta/b.bin
  models/beta-LICENSE .installed-v1 .installed-v2)
for w in "${want[@]}"; do [ -f "$data/$w" ] || fail "fresh install lacks $w"; done
grep -q "^alpha 1.0.0 sub/a3.txt$" "$data/training/alpha/third.txt" 2>/dev/null || fail "third.txt has the wrong content"
[ -f "$data/downloads/avatar-test-alpha-1.0.0.tgz" ] || fail "the 'keep' tarball of alpha was deleted"
[ ! -f "$data/downloads/avatar-test-beta-2.0.0.tgz" ] || fail "the 'drop' tarball of beta was kept"
grep -q "^npm @avatar-test/alpha@1.0.0 $sha_alpha$" "$data/PROVENANCE.txt" || fail "PROVENANCE.txt lacks alpha"
grep -q "^training/: made-up note$" "$data/PROVENANCE.txt" || fail "PROVENANCE.txt lacks the note"
# Up to date: nothing is fetched or copied again.
touch -d "2000-01-01" "$data/models/a1.txt"
if run_setup && grep -q "Data: present in $data" "$work/setup.log"; then echo "setup: an up-to-date folder is kept as it is"
else cat "$work/setup.log"; fail "setup did not recognise an up-to-date folder"; fi
[ "$(stat -c %Y "$data/models/a1.txt")" = "$(date -d 2000-01-01 +%s)" ] || fail "an up-to-date file was rewritten"
# A version-1 folder (v2 files and stamp removed): the upgrade copies only the v2 files, from
# alpha's kept tarball and beta's, without touching the v1 files or the registry.
rm -rf "$data/.installed-v2" "$data/models/beta" "$data/models/beta-LICENSE" "$data/training"
cp "$work/tarballs/avatar-test-beta-2.0.0.tgz" "$data/downloads/"
before_v1=$(stat -c %Y "$data/models/a1.txt")
if run_setup && grep -q "Data: upgrading $data from v1 to v2" "$work/setup.log"; then echo "setup: v1 folder upgraded to v2"
else cat "$work/setup.log"; fail "setup did not upgrade a v1 folder"; fi
for w in "${want[@]}"; do [ -f "$data/$w" ] || fail "upgraded folder lacks $w"; done
[ "$(stat -c %Y "$data/models/a1.txt")" = "$before_v1" ] || fail "the upgrade rewrote a version-1 file"
[ "$(grep -c "^Avatar Studio data v" "$data/PROVENANCE.txt")" = 3 ] || fail "PROVENANCE.txt should have 3 entries (v1, v2, v2 again)"
# Without the tarballs the upgrade has to download; with no registry it must say so clearly.
rm -rf "$data/.installed-v2" "$data/downloads"/*
if run_setup; then fail "setup upgraded without alpha's tarball and without a registry"
elif grep -q "could not download @avatar-test/alpha@1.0.0 from the npm registry (http://127.0.0.1:9/)" "$work/setup.log"; then
  echo "setup: a missing tarball is fetched again (and says so when the registry is unreachable)"
else cat "$work/setup.log"; fail "unclear message for a missing tarball"; fi

# 3. The data folder the tests use holds every file of the real list.
real="${AVATAR_DATA_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/avatar-studio}"
if ! ls "$real"/.installed-v* >/dev/null 2>&1; then
  fail "no data folder at $real: run scripts/setup first (the other tests need it too)"
else
  count=0
  while IFS=$'\t' read -r kind _ _ member dest _; do
    [ "$kind" = file ] || continue
    if [[ "$dest" == */ ]]; then path="$real/$dest${member##*/}"; else path="$real/$dest"; fi
    if compgen -G "$path" >/dev/null; then count=$((count + 1)); else fail "the data folder lacks $path"; fi
  done < <(grep -v '^#' "$list")
  echo "data folder $real holds all $count listed files"
fi
[ $status -eq 0 ] && echo "OK"
exit $status
