# Sourced by ./test and ./demo: makes a fresh machine able to build and test
# smokenav. Installs only what is missing; says what it installs.

# A Rust toolchain (rustup, stable, minimal profile plus rustfmt and clippy)
# when the machine has none.
ensure_rust() {
    if command -v cargo >/dev/null; then return; fi
    if [ ! -x "$HOME/.cargo/bin/cargo" ]; then
        command -v curl >/dev/null || { echo "needs curl (or a Rust toolchain: https://rustup.rs)" >&2; exit 1; }
        echo "no Rust toolchain: installing one with rustup (stable, minimal profile) …" >&2
        curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs |
            sh -s -- -y --profile minimal --default-toolchain stable --component rustfmt,clippy
    fi
    export PATH="$HOME/.cargo/bin:$PATH"
}

# ensure_debian_packages COMMAND=PACKAGE ...: installs each PACKAGE whose
# COMMAND is not on the PATH.
ensure_debian_packages() {
    local missing=() pair
    for pair in "$@"; do
        command -v "${pair%%=*}" >/dev/null 2>&1 || missing+=("${pair#*=}")
    done
    [ ${#missing[@]} -eq 0 ] || install_debian_packages "${missing[@]}"
}

# install_debian_packages PACKAGE ...: apt-get install, as root or through
# passwordless sudo; otherwise says what to install and stops.
install_debian_packages() {
    local missing=("$@")
    local sudo=()
    if [ "$(id -u)" -ne 0 ]; then
        if sudo -n true 2>/dev/null; then sudo=(sudo -n); else
            echo "the tests need these Debian packages: ${missing[*]}" >&2
            echo "install them (sudo apt-get install ${missing[*]}) or run as root" >&2
            exit 1
        fi
    fi
    echo "installing Debian packages: ${missing[*]}" >&2
    "${sudo[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq "${missing[@]}" >/dev/null
}
