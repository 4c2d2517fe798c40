#!/usr/bin/env bash
# The README's first command: the demo on a fresh machine with only a Rust toolchain.
#
# railview draws with wgpu, on a GPU where there is one and otherwise on Mesa's software
# drivers: Vulkan (lavapipe) or OpenGL ES through EGL (llvmpipe), whichever is there. As root
# on Debian or Ubuntu this first installs the ones that are missing; without root it says
# which are missing and runs the demo anyway (it uses what the machine has; a stage that
# finds no GPU driver at all is reported with the packages to install, and the others still
# run). Then it builds railview and runs `railview demo` with the arguments given, e.g.
#   ./scripts/demo.sh --no-window --face-size 128
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/packages.sh
. scripts/packages.sh

ensure_packages lenient mesa-vulkan-drivers libvulkan1 libegl1 libegl-mesa0 libgl1-mesa-dri
ensure_runtime_dir
exec cargo run --release --locked -- demo "$@"
