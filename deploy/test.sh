#!/usr/bin/env bash
# Installs what is missing, builds, fetches the real test scans and runs every test.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
install_packages
build_all
bash "$POINTILLIST_ROOT/deploy/fetch-test-data.sh"
cd "$POINTILLIST_BUILD"
log "running the test suite (ctest)"
ctest --output-on-failure --timeout 600 "$@"
