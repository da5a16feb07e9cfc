#!/usr/bin/env bash
# Install what cfddem needs from Debian 12 packages (idempotent; needs root or sudo).
set -euo pipefail
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
pkgs=(cmake ninja-build g++ make libopenmpi-dev openmpi-bin libtbb-dev libeigen3-dev
      libhdf5-openmpi-dev libhypre-dev libgtest-dev libbenchmark-dev libcli11-dev
      libtomlplusplus-dev libfmt-dev nlohmann-json3-dev python3-numpy python3-scipy
      python3-matplotlib python3-h5py)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" > /dev/null
fi
