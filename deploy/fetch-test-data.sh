#!/usr/bin/env bash
# Unpacks the real scans and meshes that Debian's libcgal-demo ships into
# .cache/cgal-data/data/... without installing the package (its dependencies
# pull in CGAL, Qt and Boost, which Pointillist does not need).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cache="$root/.cache"
dest="$cache/cgal-data"
if [[ -f "$dest/data/meshes/bunny00.off" && -f "$dest/data/points_3/building.ply" ]]; then
  exit 0
fi
mkdir -p "$cache/deb"
tarball=/usr/share/doc/libcgal-dev/data.tar.gz
if [[ ! -f "$tarball" ]]; then
  deb=$(ls "$cache"/deb/libcgal-demo_*.deb 2>/dev/null | head -n1 || true)
  if [[ -z "$deb" ]]; then
    echo "fetch-test-data: downloading libcgal-demo from the Debian archive" >&2
    (cd "$cache/deb" && apt-get download libcgal-demo >/dev/null) || {
      apt-get update -qq && (cd "$cache/deb" && apt-get download libcgal-demo >/dev/null)
    }
    deb=$(ls "$cache"/deb/libcgal-demo_*.deb | head -n1)
  fi
  rm -rf "$cache/deb/x"
  dpkg-deb -x "$deb" "$cache/deb/x"
  tarball="$cache/deb/x/usr/share/doc/libcgal-dev/data.tar.gz"
fi
rm -rf "$dest.tmp" && mkdir -p "$dest.tmp"
tar -xzf "$tarball" -C "$dest.tmp" data/meshes data/points_3
rm -rf "$dest" && mv "$dest.tmp" "$dest"
rm -rf "$cache/deb/x"
echo "fetch-test-data: real scans in $dest/data" >&2
