#!/usr/bin/env bash
# Headless Chromium for the report check (tests/headless/test_demo.py opens report.html in it).
# Installs Debian's chromium when no chromium/chrome binary is on PATH.
set -euo pipefail
for b in chromium chromium-browser google-chrome; do
  if command -v "$b" >/dev/null; then exit 0; fi
done
echo "ensure_chromium: installing Debian's chromium (headless report check)" >&2
bash "$(dirname "$0")/apt_install.sh" chromium
