#!/usr/bin/env bash
# Times the README's two commands on a fresh Debian 12 machine: a debootstrap chroot (a standard
# base: the required and important packages, as the installer leaves a machine without a desktop),
# run as root with proc, sys and dev bound in, into which this repository's committed HEAD is
# cloned (by the host's git: a user clones before running anything, and the base has no git).
#   scripts/fresh_machine_timing.sh TARGET_DIR
# TARGET_DIR is created with debootstrap when absent (about 300 MB; the network must reach
# deb.debian.org). An existing TARGET_DIR must be unused (no /root/terrastride): a set-up is timed
# once per machine. The chroot is kept afterwards, unmounted; its logs are in TARGET_DIR/timing/.
# Then, inside it:
#   1. bash scripts/setup.sh && ./build/terrastride demo
#   2. bash scripts/setup.sh --tests && ctest --test-dir build -L fast --output-on-failure -j 2
# and prints a table: each command's wall and CPU time, setup.sh's steps (package install, npm ci,
# build), the .deb files apt downloaded, and the load outside (the machine may be shared: CPU
# seconds are the robust figure, wall times depend on the load).
set -euo pipefail

usage() { echo "usage: $0 TARGET_DIR" >&2; exit 2; }
[ $# -eq 1 ] || usage
case "$1" in -*) usage ;; esac
[ "$(id -u)" -eq 0 ] || { echo "$0: must run as root (debootstrap, chroot, mount)" >&2; exit 1; }
repo=$(cd "$(dirname "$0")/.." && pwd)
target=$(realpath -m "$1")
mirror=http://deb.debian.org/debian

if [ ! -e "$target" ]; then
  command -v debootstrap >/dev/null 2>&1 || {
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >/dev/null
  }
  echo "fresh_machine_timing: debootstrap bookworm $target"
  debootstrap bookworm "$target" "$mirror" >"$target.debootstrap.log" 2>&1 || {
    echo "$0: debootstrap failed, see $target.debootstrap.log" >&2; exit 1; }
fi
[ -x "$target/usr/bin/apt-get" ] || { echo "$0: $target is not a Debian root (no usr/bin/apt-get)" >&2; exit 1; }
if [ -e "$target/root/terrastride" ]; then
  echo "$0: $target was used already ($target/root/terrastride exists): a fresh machine is timed" \
       "once; remove it or name a new folder" >&2
  exit 1
fi

# The machine as the Debian 12 installer leaves it: the release, its updates and security
# archives. debootstrap's own .deb files are removed so that the archive cache afterwards holds
# exactly what the set-up downloaded.
cat >"$target/etc/apt/sources.list" <<EOF
deb $mirror bookworm main
deb $mirror bookworm-updates main
deb http://deb.debian.org/debian-security bookworm-security main
EOF
cp -L /etc/resolv.conf "$target/etc/resolv.conf"
# A host whose network intercepts TLS names its extra certificate authorities in
# NODE_EXTRA_CA_CERTS; the chroot gets them too, so that npm reaches the registry as on the host.
extra_env=()
if [ -n "${NODE_EXTRA_CA_CERTS:-}" ] && [ -f "$NODE_EXTRA_CA_CERTS" ]; then
  cp -L "$NODE_EXTRA_CA_CERTS" "$target/etc/host-extra-ca.crt"
  extra_env=(NODE_EXTRA_CA_CERTS=/etc/host-extra-ca.crt)
fi
chroot "$target" apt-get clean
logs="$target/timing"
mkdir -p "$logs"

mounted=()
cleanup() {
  [ -n "${load_pid:-}" ] && kill "$load_pid" 2>/dev/null || true
  local m
  for m in "${mounted[@]}"; do umount -R "$m" 2>/dev/null || umount -lR "$m" || true; done
}
trap cleanup EXIT
mount -t proc proc "$target/proc" && mounted+=("$target/proc")
for d in sys dev; do
  mount --rbind "/$d" "$target/$d" && mount --make-rslave "$target/$d" && mounted+=("$target/$d")
done

git clone --quiet --no-hardlinks "$repo" "$target/root/terrastride"
commit=$(git -C "$target/root/terrastride" log -1 --format='%h %s' | cut -c1-72)
packages_before=$(chroot "$target" dpkg-query -W -f='${Status}\n' | grep -c "install ok installed")

# The load outside, every 10 s, while the commands run.
(while sleep 10; do cut -d' ' -f1 /proc/loadavg; done) >"$logs/load" &
load_pid=$!

# run_in_chroot NAME COMMAND: COMMAND in the clone as root with a clean login environment;
# /usr/bin/time (the host's: the base has none) measures the whole process tree.
run_in_chroot() {
  local name=$1 command=$2
  echo "fresh_machine_timing: $name: $command"
  local status=0
  /usr/bin/time -v -o "$logs/$name.time" \
    chroot "$target" /usr/bin/env -i HOME=/root LANG=C.UTF-8 TERM=dumb \
      PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin "${extra_env[@]}" \
      bash -c "cd /root/terrastride && $command" >"$logs/$name.log" 2>&1 || status=$?
  tail -n 3 "$logs/$name.log"
  [ "$status" -eq 0 ] || { echo "$0: $name failed (exit $status), see $logs/$name.log" >&2; exit 1; }
}
debs() {  # the number and MB of the .deb files in the chroot's archive cache
  find "$target/var/cache/apt/archives" -maxdepth 1 -name '*.deb' -printf '%s\n' |
    awk '{ n++; s += $1 } END { printf "%d .deb, %.1f MB", n, s / 1e6 }'
}

run_in_chroot command1 \
  "bash scripts/setup.sh && TIMEFORMAT='demo: %R s wall, %U s user, %S s sys' && time ./build/terrastride demo"
debs1=$(debs)
packages_after1=$(chroot "$target" dpkg-query -W -f='${Status}\n' | grep -c "install ok installed")
npm_cache=$(du -sm "$target/root/.npm" 2>/dev/null | cut -f1 || echo 0)
run_in_chroot command2 \
  "bash scripts/setup.sh --tests && ctest --test-dir build -L fast --output-on-failure -j 2"
debs2=$(debs)
packages_after2=$(chroot "$target" dpkg-query -W -f='${Status}\n' | grep -c "install ok installed")
kill "$load_pid" 2>/dev/null || true
load_pid=

# ---- the table ----
time_of() {  # time_of NAME: "WALL s wall, CPU s CPU" of a whole command from /usr/bin/time -v
  awk -F': ' '/Elapsed \(wall clock\)/ { n = split($2, p, ":"); w = 0; for (i = 1; i <= n; i++) w = w * 60 + p[i] }
              /User time/ { u = $2 } /System time/ { s = $2 }
              END { printf "%.1f s wall, %.1f s CPU (%.2f CPU-min)", w, u + s, (u + s) / 60 }' "$logs/$1.time"
}
steps_of() { grep -E '^setup.sh: step |^demo: ' "$logs/$1.log" | sed 's/^setup.sh: step /  setup.sh /; s/^demo: /  demo: /'; }
echo
echo "fresh Debian 12 (debootstrap bookworm) at $target, $(nproc) CPUs, commit $commit"
echo "README command 1: bash scripts/setup.sh && ./build/terrastride demo"
echo "  whole: $(time_of command1)"
steps_of command1
echo "  apt downloaded: $debs1; installed packages $packages_before -> $packages_after1; npm cache ${npm_cache} MB"
echo "README command 2: bash scripts/setup.sh --tests && ctest --test-dir build -L fast -j 2"
echo "  whole: $(time_of command2)"
steps_of command2
echo "  ctest: $(grep -E 'tests passed|tests failed out of' "$logs/command2.log" | tail -n 1)"
echo "  apt downloaded in all: $debs2; installed packages $packages_after2"
awk '{ s += $1; n++; if (n == 1 || $1 < lo) lo = $1; if ($1 > hi) hi = $1 }
     END { if (n) printf "load outside (1-min average, every 10 s): %.2f mean, %.2f-%.2f\n", s / n, lo, hi }' \
  "$logs/load"
