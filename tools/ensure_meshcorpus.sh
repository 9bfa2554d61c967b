#!/usr/bin/env bash
# The real-mesh training corpus (blender_addon/core/mesh_corpus.py): the mesh files of Debian's
# libcgal-demo (data.tar.gz: data/meshes) and openscad-testing-data (testdata), unpacked into DEST
# (default corpora/meshes). `apt-get download` fetches the two .deb files without installing them
# (no root, no dependencies: libcgal-demo would pull libcgal-dev and Boost); an installed package's
# files are used instead where present. Idempotent: DEST/.complete marks a finished unpack.
set -euo pipefail
DEST="${1:-corpora/meshes}"
if [ -f "$DEST/.complete" ]; then exit 0; fi
echo "ensure_meshcorpus: unpacking libcgal-demo and openscad-testing-data meshes into $DEST" >&2
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
CGAL_TAR=/usr/share/doc/libcgal-dev/data.tar.gz
SCAD_DIR=/usr/share/openscad/testdata
if [ ! -f "$CGAL_TAR" ] || [ ! -d "$SCAD_DIR" ]; then
  (cd "$TMP" && apt-get download libcgal-demo openscad-testing-data >/dev/null 2>"$TMP/apt.log") || {
    cat "$TMP/apt.log" >&2
    echo "ensure_meshcorpus: apt-get download libcgal-demo openscad-testing-data failed (a Debian/Ubuntu apt source is needed)" >&2
    exit 1; }
  for deb in "$TMP"/*.deb; do dpkg-deb -x "$deb" "$TMP/root"; done
  CGAL_TAR="$TMP/root/usr/share/doc/libcgal-dev/data.tar.gz"
  SCAD_DIR="$TMP/root/usr/share/openscad/testdata"
fi
rm -rf "$DEST.partial" && mkdir -p "$DEST.partial/libcgal-demo" "$DEST.partial/openscad-testing-data"
tar xzf "$CGAL_TAR" -C "$TMP" data/meshes
cp -p "$TMP"/data/meshes/*.{off,ply,stl} "$DEST.partial/libcgal-demo/"
(cd "$SCAD_DIR" && find . -type f \( -iname '*.stl' -o -iname '*.off' \)) | while read -r f; do
  mkdir -p "$DEST.partial/openscad-testing-data/$(dirname "$f")"
  cp -p "$SCAD_DIR/$f" "$DEST.partial/openscad-testing-data/$f"
done
touch "$DEST.partial/.complete"
rm -rf "$DEST" && mv "$DEST.partial" "$DEST"
