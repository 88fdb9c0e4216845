#!/usr/bin/env bash
# Installs what `cargo build --release --features mpi` needs on Debian or Ubuntu: MPICH (its
# library, headers and mpirun) and libclang, with which the `mpi` crate generates its bindings.
# Run as root, or as a user whom sudo lets install packages. Exit status 1 where the packages
# cannot be had (no apt-get, no root, no network): the MPI build is then not possible here.
set -euo pipefail
packages=(mpich libmpich-dev libclang-dev)
if ! command -v apt-get >/dev/null 2>&1; then
    echo "install-mpi: no apt-get here; install MPICH (with its headers) and libclang by hand" >&2
    exit 1
fi
if [ "$(id -u)" -eq 0 ]; then
    run=()
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    run=(sudo)
else
    echo "install-mpi: root (or password-less sudo) is needed to install ${packages[*]}" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
# a list of packages already fresh enough is not fetched again
if ! dpkg -s "${packages[@]}" >/dev/null 2>&1; then
    "${run[@]}" apt-get update -qq
    "${run[@]}" apt-get install -y -qq "${packages[@]}" >/dev/null
fi
mpirun --version | head -n 2
