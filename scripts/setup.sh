#!/usr/bin/env bash
# One idempotent set-up for a fresh Debian 12 machine (run as root, or with sudo available):
# installs the Debian packages terrastride needs, then configures and builds it. Each mode
# installs only its own packages: the release build's, and the test tools with the tests.
#   scripts/setup.sh              Release build of the terrastride binary in build/
#   scripts/setup.sh --tests      and the fast tests (`ctest --test-dir build -L fast`), with
#                                 GoogleTest and Google Benchmark
#   scripts/setup.sh --all        and everything else: the slow tests (with Chromium and Python)
#                                 and the benchmarks
#   scripts/setup.sh --sanitize   ASan+UBSan build of the fast tests in build-asan/
#   scripts/setup.sh --deps-only  the release build's packages only
#   scripts/setup.sh --fuzz-deps  those and clang + libFuzzer runtime (for tests/fuzz/run.sh)
# scripts/fresh_machine_timing.sh times the README's commands on a fresh Debian 12 (a chroot).
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

# What the release build and the demo need; the tests' and the fuzzers' packages come with
# their modes (below), so README's first command installs no test tools.
packages=(
  build-essential cmake ninja-build pkg-config ccache
  libeigen3-dev liboctomap-dev libfcl-dev libceres-dev coinor-libipopt-dev
  # MuJoCo 2.2.2: `terrastride simulate` executes plans in it (simulation/). Its CMake config
  # requires OpenGL's and names Qhull's headers, packages libmujoco-dev does not depend on.
  libmujoco-dev libgl-dev libopengl-dev libqhull-dev
  # ALGLIB: the simulated controller's stance-force quadratic program (simulate
  # --force-distribution constrained); Debian 12 packages no other QP solver.
  libalglib-dev
  # Ipopt's MUMPS spends ~80 % of a plan in dense BLAS kernels; Debian's default generic ATLAS
  # is ~25 % slower there than OpenBLAS, which takes over libblas.so.3 by alternatives priority.
  libopenblas0-serial
  nlohmann-json3-dev libcli11-dev libasio-dev libyaml-cpp-dev
  # Bags as map input (perception/src/bag): MCAP chunks (zstd, lz4, zlib's CRC-32), ROS 2 .db3
  # (SQLite), ROS 1 .bag (rosbag_storage; its headers include pluginlib's).
  libzstd-dev liblz4-dev zlib1g-dev libsqlite3-dev librosbag-storage-dev
  # URDF import (`terrastride robot import`): urdfdom parses the URDF.
  liburdfdom-dev
  # The offline report inlines a plotting library installed with npm (service/report).
  nodejs
)
# PCL (perception's cloud readers and filters). Debian 12 ships PCL's headers and CMake config only
# in libpcl-dev, which depends on libvtk9-dev, and that on default-jdk, Qt, GDAL, HDF5-MPI,
# FFmpeg and PostgreSQL's and MySQL's headers: 435 MB and 530 packages on top of the rest of a
# fresh machine's download (239 MB, 658), for PCL's visualisation, which terrastride does not use;
# PCL's runtime libraries (VTK's with them: libpcl-io links it) are 93 MB and 96. So unless
# libpcl-dev is installed already, this installs the runtime libraries of the components
# terrastride links (their names carry PCL's version) and the Boost and FLANN headers PCL's include,
# and unpacks libpcl-dev's own .deb, of the same version, into /opt/terrastride (unpack_pcl_headers
# below: dpkg does not record it, nothing under /usr changes); CMake reads its PCLConfig.cmake.
pcl_components=(common io filters kdtree search octree sample-consensus segmentation)
pcl_version=1.13  # Debian 12's
installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
if installed libpcl-dev; then
  pcl_unpacked=no
else
  pcl_unpacked=yes
  for c in "${pcl_components[@]}"; do packages+=("libpcl-$c$pcl_version"); done
  packages+=(libflann-dev libboost-system-dev libboost-filesystem-dev libboost-date-time-dev
             libboost-iostreams-dev libboost-serialization-dev)
fi
# The machine image's Node.js bundles npm; Debian's npm package only when it does not.
command -v npm >/dev/null 2>&1 || packages+=(npm)
# The tests (GoogleTest, GoogleMock) and benchmarks (Google Benchmark, configured with the tests).
test_packages=(libgtest-dev libgmock-dev libbenchmark-dev)
case "$mode" in
  tests|sanitize) packages+=("${test_packages[@]}") ;;
  # The slow suite: the report opened in headless Chromium (test_report, test_report_views), the
  # Python client against the server (test_server).
  all) packages+=("${test_packages[@]}" chromium python3) ;;
  fuzz) packages+=(clang libclang-rt-14-dev) ;;
esac
missing=()
for p in "${packages[@]}"; do installed "$p" || missing+=("$p"); done
sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup.sh: installing ${#missing[@]} Debian packages: ${missing[*]}"
  step_begin packages
  "${sudo_cmd[@]}" apt-get update -qq
  # dpkg's unsafe I/O (no fsync before each unpacked file's rename, as Debian's container images
  # set it): the packages' tens of thousands of small files (Boost's headers, npm's Node.js
  # modules) make the install wait on the disk; reinstalling Boost's headers and two Node.js
  # packages took 71-91 s instead of 130-145 s. The risk, empty files after a crash during the
  # install, is repaired by running setup.sh again after `apt-get install --reinstall`.
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends \
    -o Dpkg::Options::=--force-unsafe-io "${missing[@]}" >/dev/null
  step_end
fi

# unpack_pcl_headers: libpcl-dev's files (headers, PCLConfig.cmake, the libpcl_*.so link names)
# for the installed PCL version in /opt/terrastride/libpcl-dev_VERSION, written whole or not at
# all; its link names are pointed at the installed libraries. Sets pcl_config_dir.
unpack_pcl_headers() {
  local version root tmp link
  version=$(dpkg-query -W -f='${Version}' "libpcl-common$pcl_version")
  root=/opt/terrastride/libpcl-dev_$version
  if [ ! -d "$root" ]; then
    echo "setup.sh: unpacking libpcl-dev $version (PCL's headers and CMake config) into $root"
    step_begin "libpcl-dev unpack"
    "${sudo_cmd[@]}" mkdir -p /opt/terrastride
    tmp=$("${sudo_cmd[@]}" mktemp -d /opt/terrastride/.unpack.XXXXXX)
    # apt fetches as its unprivileged user _apt, which must be able to write there.
    "${sudo_cmd[@]}" chown _apt "$tmp" 2>/dev/null || true
    "${sudo_cmd[@]}" sh -c 'cd "$1" && { apt-get download -qq "libpcl-dev=$2" 2>/dev/null ||
      { apt-get update -qq && apt-get download -qq "libpcl-dev=$2"; }; }' sh "$tmp" "$version" || {
      echo "setup.sh: cannot download libpcl-dev=$version, the installed PCL's version (is PCL older" \
           "than the archive's? apt-get upgrade, then run setup.sh again)" >&2
      "${sudo_cmd[@]}" rm -rf "$tmp"
      exit 1
    }
    "${sudo_cmd[@]}" dpkg-deb -x "$tmp"/libpcl-dev_*.deb "$tmp/tree"
    for link in "$tmp"/tree/usr/lib/*/libpcl_*.so; do
      "${sudo_cmd[@]}" ln -sfn "/usr/lib/$(basename "$(dirname "$link")")/$(readlink "$link")" "$link"
    done
    "${sudo_cmd[@]}" mv "$tmp/tree" "$root"
    "${sudo_cmd[@]}" rm -rf "$tmp"
    step_end
  fi
  pcl_config_dir=$(echo "$root"/usr/lib/*/cmake/pcl)
}
cmake_pcl=()
if [ "$pcl_unpacked" = yes ]; then
  unpack_pcl_headers
  cmake_pcl=(-DPCL_DIR="$pcl_config_dir")
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
    -DTERRASTRIDE_BUILD_BENCHMARKS=OFF "${cmake_pcl[@]}" >/dev/null
  cmake --build build-asan -j "$jobs" --target fast_tests
else
  # The tests are configured when their packages are installed (always with --tests and --all; a
  # plain set-up after those keeps them).
  testing=ON
  for p in "${test_packages[@]}"; do installed "$p" || testing=OFF; done
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=$testing \
    "${cmake_pcl[@]}" >/dev/null
  # The binary first (the demo's: it is ready before any test compiles), then the tests and
  # benchmarks only when asked: they are most of a full build's compile time.
  cmake --build build -j "$jobs" --target terrastride
  case "$mode" in
    tests) cmake --build build -j "$jobs" --target fast_tests ;;
    all) cmake --build build -j "$jobs" ;;
  esac
fi
step_end
