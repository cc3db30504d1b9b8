#!/usr/bin/env bash
# The tools that build and run the native FMUs' other platforms (Debian/Ubuntu, as root):
# the mingw-w64 and aarch64 cross-compilers (win64 and aarch64-linux binaries where no Zig
# is installed: the tests of that fallback, export-c's strict builds), wine and qemu-user
# with Debian's aarch64 C library (the tests run the C host built for those platforms),
# clang (the FMUs' sources are compiled alone with gcc and clang), valgrind, and the
# bare-metal Arm compiler with its C library (gcc-arm-none-eabi, libnewlib-arm-none-eabi:
# `delaycomp export-c` controllers are built for a Cortex-M4).
# .ci/run calls it; the tests that need a tool say in pytest's summary when it is missing.
# Best effort: a package that cannot be installed is reported, and the script goes on.
set -u
PACKAGES="gcc-mingw-w64-x86-64 gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user wine wine64 clang valgrind gcc-arm-none-eabi libnewlib-arm-none-eabi"
missing=""
for p in $PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -z "$missing" ]; then
    echo "install_platform_tools: all installed"
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1 || [ "$(id -u)" != 0 ]; then
    echo "install_platform_tools: not installed:$missing (needs apt-get as root); the tests that need them report it" >&2
    exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null 2>&1 || echo "install_platform_tools: apt-get update failed" >&2
# shellcheck disable=SC2086
if ! apt-get install -y -qq --no-install-recommends $missing >/dev/null 2>&1; then
    echo "install_platform_tools: apt-get install$missing failed; the tests that need them report it" >&2
fi
exit 0
