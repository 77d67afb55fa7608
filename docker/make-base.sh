#!/usr/bin/env bash
# Make a base image for docker/Dockerfile from Debian's packages alone, for hosts that
# cannot pull python:3.11-slim-bookworm: a minimal Debian bookworm (debootstrap
# --variant=minbase) with Debian's Python 3.11 (python3, python3-venv, `python`), imported
# into Podman (or Docker) as camnet-base:bookworm. Needs root (debootstrap) and a Debian
# mirror; nothing is pulled from a container registry.
#
#   docker/make-base.sh [-f] [-t TAG] [-m MIRROR] [-e podman|docker]
#   podman build -f docker/Dockerfile --build-arg PYTHON_IMAGE=localhost/camnet-base:bookworm -t camnet .
#
# -f makes it again when TAG exists; -m is the Debian mirror (default
# http://deb.debian.org/debian; the image's security updates come from MIRROR-security).
set -euo pipefail

tag=camnet-base:bookworm
mirror=http://deb.debian.org/debian
engine=podman
force=0
usage="usage: $0 [-f] [-t TAG] [-m MIRROR] [-e podman|docker]"
while getopts "ft:m:e:h" opt; do
  case $opt in
    f) force=1 ;;
    t) tag=$OPTARG ;;
    m) mirror=${OPTARG%/} ;;
    e) engine=$OPTARG ;;
    *) echo "$usage" >&2; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
[ $# -eq 0 ] || { echo "$usage" >&2; exit 2; }
for tool in debootstrap "$engine"; do
  command -v "$tool" >/dev/null || { echo "make-base: $tool not found (Debian: apt-get install $tool)" >&2; exit 1; }
done
[ "$(id -u)" = 0 ] || { echo "make-base: debootstrap needs root" >&2; exit 1; }
if [ "$force" = 0 ] && "$engine" image inspect "$tag" >/dev/null 2>&1; then
  echo "make-base: $tag exists (-f to make it again)"
  exit 0
fi

# The Debian release whose python3 is what pyproject.toml's requires-python (>=3.11) and
# the Dockerfile's default base (python:3.11-slim-bookworm) have.
suite=bookworm
root=$(mktemp -d "${TMPDIR:-/tmp}/camnet-base.XXXXXX")
trap 'rm -rf "$root"' EXIT
echo "make-base: debootstrap $suite from $mirror" >&2
if ! debootstrap --variant=minbase --include=python3,python3-venv,python-is-python3 \
       "$suite" "$root/fs" "$mirror" >"$root/debootstrap.log" 2>&1; then
  tail -n 20 "$root/debootstrap.log" >&2
  [ -f "$root/fs/debootstrap/debootstrap.log" ] && tail -n 20 "$root/fs/debootstrap/debootstrap.log" >&2
  echo "make-base: debootstrap failed" >&2
  exit 1
fi
cat >"$root/fs/etc/apt/sources.list" <<EOF
deb $mirror $suite main
deb $mirror $suite-updates main
deb $mirror-security $suite-security main
EOF
# Nothing of this host in the image: the engine provides hostname and resolv.conf.
rm -rf "$root"/fs/var/cache/apt/archives/*.deb "$root"/fs/var/lib/apt/lists/* "$root"/fs/var/log/* \
       "$root"/fs/tmp/* "$root/fs/etc/hostname" "$root/fs/etc/resolv.conf"
if ! tar --numeric-owner -C "$root/fs" -c . |
     "$engine" import \
       --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
       --change 'ENV LANG=C.UTF-8' \
       --change 'CMD ["python3"]' \
       - "$tag" >"$root/import.log" 2>&1; then
  cat "$root/import.log" >&2
  echo "make-base: $engine import failed" >&2
  exit 1
fi
python=$(chroot "$root/fs" python3 --version)
echo "make-base: $tag ($python)"
