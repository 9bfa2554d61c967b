#!/usr/bin/env bash
# Debian's assimp-testmodels: real and malformed mesh files (glTF, OBJ, PLY, STL, OFF) that the
# asset-loader corpus test (tests/blender_addon/core/test_corpus.py) runs through the loader.
set -euo pipefail
if [ -d /usr/share/assimp/models ]; then exit 0; fi
echo "ensure_testmodels: installing Debian's assimp-testmodels (mesh loader corpus test)" >&2
bash "$(dirname "$0")/apt_install.sh" assimp-testmodels
