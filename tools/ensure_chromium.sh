#!/usr/bin/env bash
# Headless Chromium for the report check (tests/headless/test_demo.py opens report.html in it).
# Installs Debian's chromium when no chromium/chrome binary is on PATH.
set -euo pipefail
for b in chromium chromium-browser google-chrome; do
  if command -v "$b" >/dev/null; then exit 0; fi
done
echo "ensure_chromium: installing Debian's chromium (headless report check)" >&2
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "ensure_chromium: not root and no sudo: run 'apt-get install chromium' as root" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq chromium >/dev/null
