# Sourced by scripts/demo and scripts/test: a virtual environment in .venv from the system's python3,
# active from here on. Debian and Ubuntu refuse a bare `pip install` outside one (PEP 668), and ship
# the venv module in a separate package (python3-venv): installed with apt-get when it is missing
# (as root, or through sudo).

# The project's own helpers print "scripts/<name>: error: ..." as the CLI does (docs/cli.md).
_script="scripts/$(basename "$0")"
die() { echo "$_script: error: $*" >&2; exit 2; }

# apt-get as root, else through sudo when there is one; nothing else is tried.
apt_install() {
    local sudo=""
    if [ "$(id -u)" != 0 ]; then
        command -v sudo >/dev/null 2>&1 || die "$1 is missing and this user cannot install it: apt-get install $*"
        sudo="sudo"
    fi
    command -v apt-get >/dev/null 2>&1 || die "$1 is missing and there is no apt-get here: install $* yourself"
    echo "$_script: installing $* (apt-get)"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@" >/dev/null
}

PYTHON="${PYTHON:-python3}"
command -v "$PYTHON" >/dev/null 2>&1 || die "no $PYTHON: gcs-pdm needs Python >= 3.10"
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 10))' || die "$PYTHON is $("$PYTHON" -V 2>&1); gcs-pdm needs >= 3.10"
VENV="${VENV:-.venv}"
if [ ! -x "$VENV/bin/python" ]; then
    if ! "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1; then
        apt_install python3-venv
    fi
    echo "$_script: creating the virtual environment $VENV"
    "$PYTHON" -m venv "$VENV"
fi
# shellcheck disable=SC1091
. "$VENV/bin/activate"
