#!/usr/bin/env bash
# Sets everything up on a fresh Debian bookworm machine: installs the
# dependencies (scripts/install_deps.sh, as root) and builds the package
# (scripts/build.sh). Safe to run again.
source "$(dirname "$0")/common.sh"
bash scripts/install_deps.sh
bash scripts/build.sh
