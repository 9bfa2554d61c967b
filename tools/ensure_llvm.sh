#!/usr/bin/env bash
# Make sure Dr.Jit's LLVM backend is active (drjit 1.5 needs LLVM >= 15; Debian 12's default
# LLVM 14 is rejected). Installs Debian's libllvm19 when the backend is inactive.
set -euo pipefail
PY=${1:-.venv/bin/python}
check() { "$PY" -c 'import sys, drjit as dr; sys.exit(0 if dr.has_backend(dr.JitBackend.LLVM) else 1)' 2>/dev/null; }
if check; then
  exit 0
fi
echo "ensure_llvm: Dr.Jit's LLVM backend is inactive; installing libllvm19 (Debian)" >&2
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "ensure_llvm: not root and no sudo: run 'apt-get install libllvm19' as root" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq libllvm19 >/dev/null
if ! check; then
  echo "ensure_llvm: LLVM backend still inactive after installing libllvm19;" \
       "set DRJIT_LIBLLVM_PATH to a libLLVM >= 15" >&2
  exit 1
fi
