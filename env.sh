# Source me:  source env.sh
# Gives a shell with the workspace, the `cartpole` command and the nodes on the path.
# - On a machine with ROS 2 Jazzy from apt (after `source /opt/ros/jazzy/setup.bash`),
#   and no .venv here: overlays this workspace's install/ on the system ROS.
# - Otherwise: activates .venv (ROS 2 Jazzy from PyPI wheels) and overlays install/ on it.
# `source env.sh --no-overlay` skips install/ (used by `make build` before it exists).
_cp_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
if [ -d "$_cp_root/.venv" ]; then
    # shellcheck disable=SC1091
    source "$_cp_root/.venv/bin/activate"
    # The wheels register their ament packages inside the venv itself.
    case ":${AMENT_PREFIX_PATH:-}:" in
        *":$VIRTUAL_ENV:"*) ;;
        *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;;
    esac
    export ROS_DISTRO="${ROS_DISTRO:-jazzy}"
    export ROS_VERSION=2
    export ROS_PYTHON_VERSION=3
elif [ -z "${ROS_DISTRO:-}" ]; then
    echo "env.sh: neither .venv nor a sourced ROS 2 found; run 'make build' or 'source /opt/ros/jazzy/setup.bash' first" >&2
fi
if [ "${1:-}" != "--no-overlay" ] && [ -f "$_cp_root/install/setup.bash" ]; then
    # shellcheck disable=SC1091
    source "$_cp_root/install/setup.bash"
    # ament_python puts executables in lib/<package>/, where `ros2 run` finds them; only
    # the `cartpole` command (and its recorder) goes on PATH, no node's generic name.
    _cp_lib="$_cp_root/install/cartpole_bringup/lib/cartpole_bringup"
    case ":$PATH:" in
        *":$_cp_lib:"*) ;;
        *) [ -d "$_cp_lib" ] && PATH="$_cp_lib:$PATH" ;;
    esac
    export PATH
    unset _cp_lib
fi
unset _cp_root
