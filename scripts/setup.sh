#!/usr/bin/env bash
# Installs what a fresh Debian 12 machine with the Rust toolchain lacks for
# alfd, then fetches the crates. Idempotent: run it again at any time.
set -euo pipefail
cd "$(dirname "$0")/.."

command -v cargo >/dev/null || { echo "setup: cargo not found; install Rust (rustup) first" >&2; exit 1; }

# Debian packages: python3 runs scripts/bench-ratios.py.
need=()
command -v python3 >/dev/null || need+=(python3)
# pip installs pymavlink below (tests/interop_pymavlink.rs plays a ground station with it).
python3 -m pip --version >/dev/null 2>&1 || need+=(python3-pip)
# libclang-dev: the v4l2 feature builds V4L2 bindings with bindgen.
dpkg -s libclang-dev >/dev/null 2>&1 || need+=(libclang-dev)
# exiftool: the capture tests read the EXIF GPS tags back.
command -v exiftool >/dev/null || need+=(libimage-exiftool-perl)
# systemd-analyze: tests/systemd_unit.rs scores the unit's hardening offline.
command -v systemd-analyze >/dev/null || need+=(systemd)
if ((${#need[@]})); then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -q
    $sudo apt-get install -y -q "${need[@]}"
fi

# pymavlink: the ground-station side of tests/interop_pymavlink.rs (which CI must run).
# pycolmap (CPU wheels from PyPI): scripts/colmap_judge.py, run by tests/colmap_judge.rs.
# mavsdk (the native binding, >= 4): scripts/mavsdk_camera.py, run by tests/mavsdk_camera.rs.
for module in pymavlink pycolmap mavsdk; do
    if ! python3 -c "import $module" 2>/dev/null; then
        python3 -m pip install --quiet "$module" 2>/dev/null \
            || python3 -m pip install --quiet --break-system-packages "$module"
    fi
done

cargo fetch --locked
echo "setup: ok"
