# The rcfile of `./uav-flock shell`: the user's own ~/.bashrc first, then the uav-flock environment, so
# that whatever the rc files put on PATH (a pyenv shim, a conda base), the venv and workspace come first.
# shellcheck disable=SC1090,SC1091
[ -f "$HOME/.bashrc" ] && source "$HOME/.bashrc"
source "$UAV_FLOCK_ROOT/tools/env.sh"
hash -r
PS1="(uav-flock) ${PS1:-\$ }"
