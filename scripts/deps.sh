#!/usr/bin/env bash
# Installs the Debian packages compend needs to build and test, only those that are missing.
#   mesa-vulkan-drivers, libvulkan1: software Vulkan (lavapipe) for the wgpu pass without a GPU
#   xvfb: a virtual X display for the projector-window tests
#   libclang-dev: bindgen, used by the V4L2 camera crates at build time
#   imagemagick: screenshots of the virtual display in tests
#   systemd, procps: systemd-analyze and /bin/kill (ExecReload=), to verify the units in systemd/
set -euo pipefail
pkgs=(mesa-vulkan-drivers libvulkan1 xvfb libclang-dev imagemagick systemd procps)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "compend: installing missing system packages: ${missing[*]}" >&2
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
