#!/bin/sh
# Builds OpenMVS's InterfaceCOLMAP and DensifyPointCloud (CPU only) for `cargo xtask bench
# dense --openmvs DIR`: the multi-view peer of the dense stage. Never needed by the tests.
#
#   xtask/scripts/build_openmvs.sh [PREFIX]        (default PREFIX: target/openmvs)
#
# Then: cargo xtask bench dense --openmvs PREFIX/build/bin   (or OPENMVS_BIN=PREFIX/build/bin)
#
# Debian 12 (bookworm) packages: Eigen, Boost, OpenCV, CGAL; the sources of OpenMVS v2.3.0 and
# of VCGLib (the fork OpenMVS pins) are cloned into PREFIX unless already there (set
# OPENMVS_SRC / VCG_SRC to use copies of your own). Takes about 7 minutes on 2 cores.
set -eu
PREFIX=$(realpath -m "${1:-target/openmvs}")
OPENMVS_SRC=${OPENMVS_SRC:-$PREFIX/openMVS}
VCG_SRC=${VCG_SRC:-$PREFIX/VCG}
OPENMVS_TAG=v2.3.0

if command -v apt-get >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO=sudo
    $SUDO apt-get install -y --no-install-recommends \
        git cmake g++ make libeigen3-dev libboost-iostreams-dev libboost-program-options-dev \
        libboost-system-dev libboost-serialization-dev libopencv-dev libcgal-dev \
        libjpeg-dev libpng-dev libtiff-dev zlib1g-dev
fi
mkdir -p "$PREFIX"
[ -d "$OPENMVS_SRC" ] || git clone --depth 1 --branch "$OPENMVS_TAG" \
    https://github.com/cdcseacave/openMVS.git "$OPENMVS_SRC"
[ -d "$VCG_SRC" ] || git clone --depth 1 https://github.com/cdcseacave/VCG.git "$VCG_SRC"

mkdir -p "$PREFIX/build"
cd "$PREFIX/build"
cmake "$OPENMVS_SRC" -DCMAKE_BUILD_TYPE=Release -DVCG_ROOT="$VCG_SRC" \
    -DOpenMVS_USE_CUDA=OFF -DOpenMVS_USE_PYTHON=OFF -DOpenMVS_USE_OPENGL=OFF \
    -DOpenMVS_USE_BREAKPAD=OFF -DOpenMVS_USE_CERES=OFF -DOpenMVS_ENABLE_TESTS=OFF
make -j"$(nproc)" InterfaceCOLMAP DensifyPointCloud
echo "OpenMVS built: $PREFIX/build/bin (cargo xtask bench dense --openmvs $PREFIX/build/bin)"
