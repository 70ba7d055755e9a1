#!/usr/bin/env bash
# Set-up shared by the README's two commands; sourced, not run. Idempotent and quiet when done before.
#  1. Debian packages: python3 + venv, and libLLVM 19 for Dr.Jit's LLVM (CPU) backend. Dr.Jit 1.5
#     aborts with Debian's default libLLVM 14/15 ("Cannot select ... fminimum"), so 19 is required.
#  2. A virtual environment in .venv with rtfit installed editable (with its test extras); reinstalled
#     only when pyproject.toml changes.
#  3. DRJIT_LIBLLVM_PATH exported explicitly, so Dr.Jit never picks an older libLLVM on its own.
# Sourcing it leaves the caller's shell options as they were (it runs with -eu -o pipefail inside and
# restores the previous settings at the end); on failure it returns 1 instead of exiting the shell.
_rtfit_saved_opts="$(set +o)"
set -euo pipefail
_rtfit_fail() { echo "rtfit setup: $*" >&2; eval "$_rtfit_saved_opts"; return 1; }
RTFIT_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export RTFIT_ROOT

_rtfit_sudo() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

_rtfit_find_llvm() {
  local f
  for f in /usr/lib/*-linux-gnu/libLLVM-19.so /usr/lib/*-linux-gnu/libLLVM-19.so.1 \
           /usr/lib/*-linux-gnu/libLLVM.so.19.1 /usr/lib/llvm-19/lib/libLLVM-19.so \
           /usr/lib/llvm-19/lib/libLLVM.so.1; do
    [ -e "$f" ] && { echo "$f"; return 0; }
  done
  return 1
}

_rtfit_need=()
command -v python3 >/dev/null 2>&1 || _rtfit_need+=(python3)
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || _rtfit_need+=(python3-venv)
_rtfit_find_llvm >/dev/null || _rtfit_need+=(libllvm19)
if [ ${#_rtfit_need[@]} -gt 0 ]; then
  echo "rtfit setup: installing Debian packages: ${_rtfit_need[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  _rtfit_sudo apt-get update -qq
  _rtfit_sudo apt-get install -y -qq --no-install-recommends "${_rtfit_need[@]}" python3-venv python3-pip ca-certificates >/dev/null
fi
DRJIT_LIBLLVM_PATH="$(_rtfit_find_llvm)" || { _rtfit_fail "libLLVM 19 not found after install"; return 1 2>/dev/null || exit 1; }
export DRJIT_LIBLLVM_PATH

RTFIT_VENV="${RTFIT_VENV:-$RTFIT_ROOT/.venv}"
export RTFIT_VENV
if [ ! -x "$RTFIT_VENV/bin/python" ]; then
  echo "rtfit setup: creating $RTFIT_VENV" >&2
  python3 -m venv "$RTFIT_VENV"
fi
_rtfit_stamp="$RTFIT_VENV/.rtfit-install-stamp"
_rtfit_want="$(sha256sum "$RTFIT_ROOT/pyproject.toml" | cut -d' ' -f1)"
if [ "$(cat "$_rtfit_stamp" 2>/dev/null)" != "$_rtfit_want" ] || ! "$RTFIT_VENV/bin/python" -c 'import rtfit.experiments' 2>/dev/null; then
  echo "rtfit setup: installing rtfit and its dependencies into $RTFIT_VENV" >&2
  "$RTFIT_VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$RTFIT_VENV/bin/python" -m pip install -q -e "$RTFIT_ROOT[test,ray]"
  echo "$_rtfit_want" > "$_rtfit_stamp"
fi
export PATH="$RTFIT_VENV/bin:$PATH"
eval "$_rtfit_saved_opts"
unset _rtfit_saved_opts
