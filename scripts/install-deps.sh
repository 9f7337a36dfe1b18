#!/usr/bin/env bash
# Installs every Debian package restird needs to build, test and benchmark, and the optional
# packages named as arguments (make bench-report: blender, the report's peer, ~300 MB).
# `--build`, anywhere among the arguments, installs only what `make` needs to build build/restir
# and build/restird (the image's build stage: no browser, fuzzer, load tools or test libraries).
# Idempotent: does nothing (and needs no network) when all packages are present.
set -euo pipefail

build_packages=(
  build-essential pkg-config
  libembree-dev          # ray tracing backend (Embree 3)
  libopenexr-dev         # EXR I/O through the C API (openexr.h)
  libdeflate-dev         # fast deflate for EXR ZIP chunks (renderer/image/exrio.c)
  libmicrohttpd-dev      # HTTP daemon
  libcjson-dev           # JSON
  libassimp-dev          # PLY / OBJ mesh loading
  python3                # scripts/embed_web.py builds the preview page into the daemon
  nodejs                 # npm ci of the page's packages (uPlot is built into the daemon)
)
test_packages=(
  python3-pytest python3-numpy python3-openimageio openimageio-tools  # tests
  embree-tools           # the benchmark peer (Embree's pathtracer tutorial)
  valgrind               # callgrind: instructions per ray (make test-perf, bench/instr_per_ray.sh)
  wrk                    # HTTP load for the server benchmark (bench/server.sh) and make load
  haproxy                # the consistent-hash router of the cluster test (make test-cluster)
  shellcheck python3-yaml  # the Dockerfile linter's shell checks; compose.yaml in the cluster test
  python3-pip python3-setuptools python3-wheel  # the Python client installed offline (tests/test_client.py)
  chromium               # browser tests of the preview page (make test-web)
  clang libclang-rt-14-dev  # libFuzzer targets (make fuzz, the smoke in make test)
)
# --build may stand anywhere among the package names (`install-deps.sh blender --build`); any
# other option is refused, so that apt never receives one as a package name.
build_only=0
extra=()
for arg in "$@"; do
  case "$arg" in
    --build) build_only=1 ;;
    -*) echo "install-deps: unknown option '$arg' (usage: install-deps.sh [--build] [PACKAGE...])" >&2; exit 2 ;;
    *) extra+=("$arg") ;;
  esac
done
packages=("${build_packages[@]}")
[ "$build_only" -eq 1 ] || packages+=("${test_packages[@]}")
# npm comes with some builds of nodejs and as Debian's own package with others.
command -v npm >/dev/null || packages+=(npm)
packages+=("${extra[@]}")

missing=()
for p in "${packages[@]}"; do
  if [ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null)" != "install ok installed" ]; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}" >&2
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo=sudo
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
