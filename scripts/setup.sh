#!/usr/bin/env bash
# Idempotent set-up of everything the project needs, from the project's own files:
#  - Debian packages: GHDL 2.0 with the LLVM back end (+ the mcode default, which we never use),
#    yosys (synthesis estimates), make, gcc (the C HAL is compiled and tested against the RTL),
#    tclsh (the Tcl files of the integration kit are run with stub commands),
#    and what a Debian python3 needs to build the venv and embed Python in the simulator;
#  - .venv with the pinned Python packages of requirements.txt / requirements.lock.
# Re-running it is cheap: it only installs what is missing or changed.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(ghdl ghdl-llvm yosys make tcl gcc)
PYTHON=${PYTHON:-python3}
if [ "$(command -v "$PYTHON")" = /usr/bin/python3 ]; then
    APT_PACKAGES+=(python3-venv libpython3-dev)
fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${missing[*]}"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
ghdl_version=$(GHDL_BACKEND=llvm ghdl --version)
case "$ghdl_version" in
    *"llvm code generator"*) ;;
    *) echo "setup: the GHDL LLVM back end is not usable:" >&2; echo "$ghdl_version" >&2; exit 1 ;;
esac

stamp=.venv/.requirements.sha256
want=$(cat requirements.txt requirements.lock | sha256sum | cut -d' ' -f1)
if [ ! -x .venv/bin/python ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "setup: creating .venv with the pinned Python packages"
    [ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -r requirements.txt -c requirements.lock
    .venv/bin/python -m pip check
    echo "$want" > "$stamp"
fi
echo "setup: ok (${ghdl_version%%$'\n'*}, LLVM back end;" \
     "$(.venv/bin/python -c 'import cocotb; print("cocotb", cocotb.__version__)'))"
