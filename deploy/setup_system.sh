#!/usr/bin/env bash
# Install the system packages pednav needs, if they are missing (Debian/Ubuntu).
#   - Mesa's OpenGL through EGL (llvmpipe) and Vulkan (lavapipe): the renderer runs
#     on them when there is no GPU; with a GPU its driver is used instead.
#   - DejaVu Sans, the font the plots (pednav-plot, pednav-eval) write text with.
#   - iproute2 (`ip`): the multi-host test across network namespaces makes its own.
# Idempotent and quiet when everything is present; needs root (or sudo) otherwise.
set -euo pipefail
packages=(libegl1 libegl-mesa0 libgl1-mesa-dri mesa-vulkan-drivers libvulkan1 fonts-dejavu-core iproute2)
missing=()
for p in "${packages[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "pednav: installing system packages: ${missing[*]}" >&2
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
