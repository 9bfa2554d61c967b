#!/usr/bin/env bash
# apt-get install the given Debian packages, as root or through sudo (used by the ensure_* scripts).
set -euo pipefail
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "apt_install: not root and no sudo: run 'apt-get install $*' as root" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq "$@" >/dev/null
