#!/usr/bin/env bash
# Runs every test of railview on a fresh Debian machine: installs what the tests need
# (POV-Ray and its scenes, Mesa's Vulkan driver for headless wgpu, Xvfb, Chromium for the
# report test), then format check, lints and the whole test suite in the one build profile
# (release) that the tools use too.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(povray povray-includes povray-examples mesa-vulkan-drivers libvulkan1 xvfb chromium slurm-wlm munge)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "missing packages: ${missing[*]} (run as root, or: sudo apt-get install ${missing[*]})" >&2
    exit 1
  fi
  echo "installing: ${missing[*]}"
  for attempt in 1 2 3; do
    if apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
      break
    fi
    [ "$attempt" = 3 ] && { echo "apt-get install failed" >&2; exit 1; }
    sleep 10
  done
fi

# Mesa prints harmless warnings without a runtime dir.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/railview-xdg}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"

cargo fmt --all --check
cargo clippy --release --workspace --all-targets --locked -- -D warnings
cargo test --release --workspace --locked
