#!/usr/bin/env bash
# One idempotent set-up for a fresh Debian machine (run as root, or with sudo available):
# installs the Debian packages terrastride needs, then configures and builds it.
#   scripts/setup.sh              Release build of the terrastride binary in build/
#   scripts/setup.sh --tests      and the fast tests (`ctest --test-dir build -L fast`)
#   scripts/setup.sh --all        and everything else: the slow tests and the benchmarks
#   scripts/setup.sh --sanitize   ASan+UBSan build of the fast tests in build-asan/
#   scripts/setup.sh --deps-only  packages only
#   scripts/setup.sh --fuzz-deps  also clang + libFuzzer runtime (for tests/fuzz/run.sh)
set -euo pipefail
cd "$(dirname "$0")/.."

mode=release
case "${1:-}" in
  "") ;;
  --tests) mode=tests ;;
  --all) mode=all ;;
  --sanitize) mode=sanitize ;;
  --deps-only) mode=deps ;;
  --fuzz-deps) mode=fuzz ;;
  *) echo "setup.sh: unknown option '$1' (use --tests, --all, --sanitize, --deps-only or --fuzz-deps)" >&2; exit 2 ;;
esac

# Each step's wall and CPU time, printed as it ends: on a fresh machine set-up takes minutes, and
# these say where they went (scripts/fresh_machine_timing.sh reads them). CPU is the finished
# children's user+system time (/proc/$$/stat fields 16-17, in clock ticks).
children_cpu_ticks() {
  local fields
  read -r -a fields 2>/dev/null < /proc/$$/stat || { echo 0; return; }
  echo $(( fields[15] + fields[16] ))
}
step_begin() { step_name=$1; step_wall0=$EPOCHREALTIME; step_cpu0=$(children_cpu_ticks); }
step_end() {
  local wall cpu
  wall=$(awk -v a="$step_wall0" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }')
  cpu=$(awk -v t=$(( $(children_cpu_ticks) - step_cpu0 )) -v hz="$(getconf CLK_TCK)" \
    'BEGIN { printf "%.1f", t / hz }')
  echo "setup.sh: step $step_name: $wall s wall, $cpu s CPU"
}

packages=(
  build-essential cmake ninja-build pkg-config ccache git
  libeigen3-dev libpcl-dev liboctomap-dev libfcl-dev libceres-dev coinor-libipopt-dev
  # MuJoCo 2.2.2: `terrastride simulate` executes plans in it (simulation/).
  libmujoco-dev
  # Ipopt's MUMPS spends ~80 % of a plan in dense BLAS kernels; Debian's default generic ATLAS
  # is ~25 % slower there than OpenBLAS, which takes over libblas.so.3 by alternatives priority.
  libopenblas0-serial
  nlohmann-json3-dev libcli11-dev libasio-dev libyaml-cpp-dev
  # Bags as map input (perception/src/bag): MCAP chunks (zstd, lz4, zlib's CRC-32), ROS 2 .db3
  # (SQLite), ROS 1 .bag (rosbag_storage; its headers include pluginlib's).
  libzstd-dev liblz4-dev zlib1g-dev libsqlite3-dev librosbag-storage-dev
  # URDF import (`terrastride robot import`): urdfdom parses the URDF.
  liburdfdom-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  python3
  # The offline report inlines a plotting library installed with npm (service/report), and its
  # test opens the report in headless Chromium.
  nodejs chromium
)
# The machine image's Node.js bundles npm; Debian's npm package only when it does not.
command -v npm >/dev/null 2>&1 || packages+=(npm)
[ "$mode" = fuzz ] && packages+=(clang libclang-rt-14-dev)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup.sh: installing ${#missing[@]} Debian packages: ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  step_begin packages
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
  step_end
fi
if [ "$mode" = deps ] || [ "$mode" = fuzz ]; then exit 0; fi

# JavaScript assets of the report and the export tests' MCAP reader (pinned by
# service/report/package-lock.json). `npm ci` only
# when the lock file changed since the last install, so re-runs stay fast and offline.
if command -v npm >/dev/null 2>&1; then
  stamp=service/report/node_modules/.terrastride-lock
  if ! cmp -s service/report/package-lock.json "$stamp" 2>/dev/null; then
    echo "setup.sh: npm ci (the report's JavaScript libraries, service/report)"
    step_begin "npm ci"
    npm ci --prefix service/report --no-audit --no-fund --loglevel=error
    cp service/report/package-lock.json "$stamp"
    step_end
  fi
fi

# Compiler cache shared by every checkout of this repository (paths hashed relative to it).
export CCACHE_BASEDIR="$PWD"

jobs=$(nproc 2>/dev/null || echo 2)
step_begin build
if [ "$mode" = sanitize ]; then
  cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTERRASTRIDE_SANITIZE=ON \
    -DTERRASTRIDE_BUILD_BENCHMARKS=OFF >/dev/null
  cmake --build build-asan -j "$jobs" --target fast_tests
else
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
  # The binary first (the demo's: it is ready before any test compiles), then the tests and
  # benchmarks only when asked: they are most of a full build's compile time.
  cmake --build build -j "$jobs" --target terrastride
  case "$mode" in
    tests) cmake --build build -j "$jobs" --target fast_tests ;;
    all) cmake --build build -j "$jobs" ;;
  esac
fi
step_end
