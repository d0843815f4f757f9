#!/usr/bin/env bash
# qemflow set-up: installs the Debian packages it needs (only those missing), builds,
# and then optionally runs the demo or the test suite.
#   ./setup.sh          install + build (Release, into build/)
#   ./setup.sh demo     ... then generate a scan-like mesh and simplify it
#   ./setup.sh test     ... then run the whole test suite with ctest
set -euo pipefail
cd "$(dirname "$0")"

PACKAGES=(build-essential cmake ninja-build pkg-config zstd
  libtbb-dev libeigen3-dev libsvm-dev libzstd-dev libopenmesh-dev
  libbenchmark-dev libgtest-dev libgmock-dev
  libcli11-dev nlohmann-json3-dev libtomlplusplus-dev libxxhash-dev
  libmeshoptimizer-dev python3-matplotlib)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

BUILD_DIR=${QEMFLOW_BUILD_DIR:-build}
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=${QEMFLOW_BUILD_TYPE:-Release} >/dev/null
cmake --build "$BUILD_DIR" -j"$(nproc)"

case "${1:-}" in
  "") ;;
  demo) exec bash scripts/demo.sh "$BUILD_DIR" ;;
  test) exec ctest --test-dir "$BUILD_DIR" --output-on-failure -j"$(nproc)" ;;
  *) echo "usage: ./setup.sh [demo|test]" >&2; exit 2 ;;
esac
