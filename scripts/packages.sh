# Sourced by scripts/demo.sh and scripts/test.sh: make sure Debian packages are installed.
#
#   ensure_packages strict|lenient PACKAGE...
#
# Installs the packages that dpkg does not list as installed, with apt-get as root (three
# tries: the package lists or the lock may be busy). Without root it says what is missing
# and how to install it; `strict` then fails, `lenient` goes on. Off Debian (no dpkg-query)
# it does nothing.

ensure_packages() {
  local mode=$1
  shift
  command -v dpkg-query >/dev/null 2>&1 || return 0
  local missing=() p
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  if [ "$(id -u)" -ne 0 ]; then
    echo "missing packages: ${missing[*]} (run as root, or: sudo apt-get install ${missing[*]})" >&2
    [ "$mode" = strict ] && return 1
    return 0
  fi
  echo "installing: ${missing[*]}"
  local attempt
  for attempt in 1 2 3; do
    if apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
      return 0
    fi
    sleep 10
  done
  echo "apt-get install ${missing[*]} failed" >&2
  [ "$mode" = strict ] && return 1
  return 0
}

# Mesa prints harmless warnings without a runtime dir.
ensure_runtime_dir() {
  export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/railview-xdg-$(id -u)}"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
}
