#!/usr/bin/env bash
# Installs the Debian packages ubake builds and tests with (DESIGN §6).
# Idempotent: runs apt-get only when something is missing.
set -eu
PKGS="build-essential cmake pkg-config libembree-dev tetgen libtet1.5-dev libcglm-dev
libopenexr-dev libtinygltf-dev nlohmann-json3-dev libstb-dev gnuplot-nox clang libclang-rt-14-dev libomp-dev"
missing=""
for p in $PKGS; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "install-deps: installing:$missing"
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing
