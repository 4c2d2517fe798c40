#!/usr/bin/env bash
# Runs every test of railview on a fresh Debian machine: installs what the tests need
# (POV-Ray and its scenes, Mesa's Vulkan driver for headless wgpu, Xvfb, Chromium for the
# report test), then format check, lints and the whole test suite in the one build profile
# (release) that the tools use too.
set -euo pipefail
cd "$(dirname "$0")/.."

# shellcheck source=scripts/packages.sh
. scripts/packages.sh
# POV-Ray and its scenes; Mesa's Vulkan and GL drivers (the renderer is tested on both);
# Xvfb (and xauth, which xvfb-run needs) for the window; Chromium for the report page.
ensure_packages strict povray povray-includes povray-examples \
  mesa-vulkan-drivers libvulkan1 libegl1 libegl-mesa0 libgl1-mesa-dri \
  xvfb xauth chromium
ensure_runtime_dir

cargo fmt --all --check
cargo clippy --release --workspace --all-targets --locked -- -D warnings
cargo test --release --workspace --locked
