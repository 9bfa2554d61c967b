#!/usr/bin/env bash
# A `blender` program for the Blender-binary tests (tests/headless/test_render.py and
# tests/blender_addon/test_package.py): Debian's package, Blender 3.4 on bookworm, older than the
# add-on supports, so those tests check the one-line refusal of an old Blender. A Blender already
# on PATH (e.g. 4.2+ from blender.org) is kept; the project itself needs none (it uses the bpy wheel).
set -euo pipefail
if command -v blender >/dev/null; then exit 0; fi
echo "ensure_blender: installing Debian's blender (the old-Blender refusal tests)" >&2
# Optional: without it the binary tests skip with their reason, so a failed install only warns.
bash "$(dirname "$0")/apt_install.sh" --no-install-recommends blender \
  || echo "ensure_blender: could not install Debian's blender; the Blender-binary tests will skip" >&2
