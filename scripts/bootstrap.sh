#!/usr/bin/env bash
# Set-up shared by the README's two commands; sourced, not run. Idempotent and quiet when done before.
#  1. Debian packages: python3 + venv, and libLLVM 19 for Dr.Jit's LLVM (CPU) backend. Dr.Jit 1.5
#     aborts with Debian's default libLLVM 14/15 ("Cannot select ... fminimum"), so 19 is required.
#  2. A virtual environment in .venv with rtfit installed editable (with its test extras); reinstalled
#     only when pyproject.toml changes.
#  3. DRJIT_LIBLLVM_PATH exported explicitly, so Dr.Jit never picks an older libLLVM on its own.
# Sourcing it leaves the caller's shell options as they were: it sets none (no set -e: under errexit a
# failing step of a sourced file would close the caller's interactive shell). Every step is checked
# instead; on failure it prints one "rtfit setup: ..." line and returns 1 (the README's scripts, which
# run with set -e, then stop).
RTFIT_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export RTFIT_ROOT

_rtfit_fail() { echo "rtfit setup: $*" >&2; return 1; }
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

_rtfit_bootstrap() {
  local need=() stamp want
  command -v python3 >/dev/null 2>&1 || need+=(python3)
  python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || need+=(python3-venv)
  _rtfit_find_llvm >/dev/null || need+=(libllvm19)
  if [ ${#need[@]} -gt 0 ]; then
    echo "rtfit setup: installing Debian packages: ${need[*]}" >&2
    DEBIAN_FRONTEND=noninteractive _rtfit_sudo apt-get update -qq || _rtfit_fail "apt-get update failed" || return 1
    DEBIAN_FRONTEND=noninteractive _rtfit_sudo apt-get install -y -qq --no-install-recommends "${need[@]}" \
      python3-venv python3-pip ca-certificates >/dev/null || _rtfit_fail "apt-get install ${need[*]} failed" || return 1
  fi
  DRJIT_LIBLLVM_PATH="$(_rtfit_find_llvm)" || _rtfit_fail "libLLVM 19 not found after install" || return 1
  export DRJIT_LIBLLVM_PATH

  RTFIT_VENV="${RTFIT_VENV:-$RTFIT_ROOT/.venv}"
  export RTFIT_VENV
  if [ ! -x "$RTFIT_VENV/bin/python" ]; then
    echo "rtfit setup: creating $RTFIT_VENV" >&2
    python3 -m venv "$RTFIT_VENV" || _rtfit_fail "could not create the virtual environment $RTFIT_VENV" || return 1
  fi
  stamp="$RTFIT_VENV/.rtfit-install-stamp"
  want="$(sha256sum "$RTFIT_ROOT/pyproject.toml" | cut -d' ' -f1)" || _rtfit_fail "cannot read pyproject.toml" || return 1
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ] || ! "$RTFIT_VENV/bin/python" -c 'import rtfit.experiments' 2>/dev/null; then
    echo "rtfit setup: installing rtfit and its dependencies into $RTFIT_VENV" >&2
    "$RTFIT_VENV/bin/python" -m pip install -q --upgrade pip >/dev/null || _rtfit_fail "pip upgrade failed" || return 1
    "$RTFIT_VENV/bin/python" -m pip install -q -e "$RTFIT_ROOT[test,ray]" || _rtfit_fail "pip install -e '.[test,ray]' failed" || return 1
    echo "$want" > "$stamp" || _rtfit_fail "cannot write $stamp" || return 1
  fi
  case ":$PATH:" in *":$RTFIT_VENV/bin:"*) ;; *) export PATH="$RTFIT_VENV/bin:$PATH" ;; esac
}

_rtfit_bootstrap
_rtfit_status=$?
unset -f _rtfit_bootstrap
if [ "$_rtfit_status" -ne 0 ]; then
  unset _rtfit_status
  return 1 2>/dev/null || exit 1  # sourced: return to the caller; run as a program: exit
fi
unset _rtfit_status
