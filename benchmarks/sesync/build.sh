#!/usr/bin/env bash
# Build SE-Sync and the sesync_rounded driver (Release).
#
#   benchmarks/sesync/build.sh SOURCE_DIR BUILD_DIR [JOBS]
#
# SOURCE_DIR: an SE-Sync work tree (github.com/david-m-rosen/SE-Sync) whose two
#   C++ submodules are filled in:
#     SOURCE_DIR/C++/Optimization     <- github.com/david-m-rosen/Optimization
#     SOURCE_DIR/C++/Preconditioners  <- github.com/david-m-rosen/Preconditioners
#   (tested with SE-Sync 9b631b6, Optimization 6d87cc2, Preconditioners 68a9d24,
#    the submodule commits SE-Sync pins).  With a full git clone:
#     git clone --recursive https://github.com/david-m-rosen/SE-Sync SOURCE_DIR
# BUILD_DIR: where everything is built (keep it outside the repository);
#   the driver ends up at BUILD_DIR/bin/sesync_rounded.
# JOBS: parallel compile jobs (default 2).
#
# System packages (Debian/Ubuntu): cmake g++ libeigen3-dev libsuitesparse-dev
#   libopenblas-dev (or any BLAS) liblapack-dev
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 SOURCE_DIR BUILD_DIR [JOBS]" >&2
  exit 2
fi
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
src="$(cd "$1" && pwd)"
build="$2"
jobs="${3:-2}"
for f in C++/CMakeLists.txt C++/Optimization/CMakeLists.txt C++/Preconditioners/CMakeLists.txt; do
  if [ ! -f "$src/$f" ]; then
    echo "$0: missing $src/$f (SE-Sync checkout with its submodules expected)" >&2
    exit 1
  fi
done
mkdir -p "$build"
cmake -S "$here" -B "$build" -DCMAKE_BUILD_TYPE=Release -DSESYNC_SOURCE_DIR="$src"
cmake --build "$build" --target sesync_rounded -j "$jobs"
echo "built: $build/bin/sesync_rounded"
