#!/usr/bin/env bash
# The main job on the built-in default: installs what is missing, builds, and
# runs a 1,2,1,4 Pointillist job on this machine.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
install_packages
build_all
log "starting the MPMD job (layout 1,2,1,4)"
bash "$POINTILLIST_ROOT/deploy/run.sh" --layout 1,2,1,4 "$@"
