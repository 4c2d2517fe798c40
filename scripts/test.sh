#!/usr/bin/env bash
# Runs every test of railview on a fresh Debian machine: installs what the tests need
# (POV-Ray and its scenes, Mesa's Vulkan and GL drivers for headless wgpu, Xvfb, Chromium for
# the report test, nginx for the static-host tests), then format check, lints and the whole
# test suite in the one build profile (release) that the tools use too; then the viewer's
# GPU tests again on wgpu's GL backend, and the README's first command end to end at a small
# size, with and without Mesa's Vulkan driver.
set -euo pipefail
cd "$(dirname "$0")/.."

# shellcheck source=scripts/packages.sh
. scripts/packages.sh
# POV-Ray and its scenes; Mesa's Vulkan and GL drivers (the renderer is tested on both);
# Xvfb (and xauth, which xvfb-run needs) for the window; Chromium for the report page;
# Slurm and munge for the batch-prerender test's single-node cluster; nginx for the static
# host and caching proxy tests (started by the tests themselves on loopback, unprivileged);
# Node.js for the browser viewer's decoder tests (tests only: the viewer needs no Node).
ensure_packages strict povray povray-includes povray-examples \
  mesa-vulkan-drivers libvulkan1 libegl1 libegl-mesa0 libgl1-mesa-dri \
  xvfb xauth chromium slurm-wlm munge nginx nodejs
ensure_runtime_dir

# The build and the tests need disk: a release target of about 2 GB (6 GB with the profile's
# incremental state; CI turns it off) and up to about 1 GB of temporary files at a time.
free_kb() { df -Pk "$1" | awk 'NR == 2 { print $4 }'; }
for dir in . "${TMPDIR:-/tmp}"; do
  if [ "$(free_kb "$dir")" -lt $((3 * 1024 * 1024)) ]; then
    echo "warning: $(cd "$dir" && pwd) has $(($(free_kb "$dir") / 1024)) MB free;" \
      "the tests need about 3 GB (set CARGO_INCREMENTAL=0 to save 4 GB of build state)" >&2
  fi
done

cargo fmt --all --check
cargo clippy --release --workspace --all-targets --locked -- -D warnings
# Every crate's documentation builds without warnings (broken intra-doc links included).
RUSTDOCFLAGS="-D warnings" cargo doc --release --workspace --no-deps --locked
cargo test --release --workspace --locked

# The renderer's GPU tests run on wgpu's default backend (Vulkan) above; once more on GL
# (about 20 s; `--workspace` keeps the features of the build above, so nothing is rebuilt).
# viewer/tests/backends.rs and tests/cli_backends.rs compare the two backends in every run.
WGPU_BACKEND=gl cargo test --release --locked --workspace \
  --test backends --test castle --test fused --test gpu --test overlays --test stream

# The README's first command at a small size (15 to 20 s each once built): as it is, and on
# a machine whose Vulkan loader finds no driver, where wgpu falls back to GL.
demo_dir=$(mktemp -d)
trap 'rm -rf "$demo_dir"' EXIT
demo_args=(--no-window --face-size 16 --walk-speed 36)
./scripts/demo.sh "${demo_args[@]}" --out "$demo_dir/default"
rm -rf "${demo_dir:?}/default"
VK_ICD_FILENAMES=/nonexistent VK_DRIVER_FILES=/nonexistent \
  ./scripts/demo.sh "${demo_args[@]}" --out "$demo_dir/without-vulkan"
