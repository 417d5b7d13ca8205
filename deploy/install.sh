#!/usr/bin/env bash
# Installs relocd on a Nao over ssh/rsync and (re)starts its systemd unit.
#
#   deploy/install.sh ROBOT [--dry-run] [--uninstall] [--robot v6|v5] [--binary FILE]
#                           [--model FILE] [--config FILE] [--after UNIT]
#
#   ROBOT          host name or address, or USER@HOST (default user: nao, who needs password-less
#                  sudo; or use root@HOST)
#   --dry-run      print every command, run none (not even the build)
#   --uninstall    stop and remove the unit and the installed files (keeps relocd.toml and recordings)
#   --robot        v6 (default) or v5: which static binary deploy/build-nao.sh builds
#   --binary FILE  install this binary instead of building one
#   --model FILE   the ONNX model (default: models/squeezenet-half-point.w8.onnx, the built-in one)
#   --config FILE  the config, replacing the robot's (default: deploy/relocd.toml, only if the robot
#                  has none yet, so edits made on the robot survive a reinstall)
#   --after UNIT   start relocd after your own service (and the camera), e.g. --after hulk.service
#
# Files go to /home/nao/relocd/ (relocd, model.onnx, relocd.toml, relocd.service); the unit to
# /etc/systemd/system/relocd.service.
set -euo pipefail
repository="$(cd "$(dirname "$0")/.." && pwd)"

usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0" >&2; exit "${1:-2}"; }
# The value of an option: the next word, which must not be another option.
value() {
    [ -n "${2:-}" ] && [[ "$2" != -* ]] || { echo "$1 needs a value" >&2; exit 2; }
    printf '%s' "$2"
}

robot_host="" dry_run=false uninstall=false robot=v6 binary="" after=""
model="" config="" replace_config=false
while [ $# -gt 0 ]; do
    case "$1" in
        --dry-run) dry_run=true ;;
        --uninstall) uninstall=true ;;
        --robot) robot="$(value "$1" "${2:-}")"; shift ;;
        --binary) binary="$(value "$1" "${2:-}")"; shift ;;
        --model) model="$(value "$1" "${2:-}")"; shift ;;
        --config) config="$(value "$1" "${2:-}")"; replace_config=true; shift ;;
        --after) after="$(value "$1" "${2:-}")"; shift ;;
        -h|--help) usage 0 ;;
        -*) echo "unknown option $1" >&2; usage ;;
        *) [ -z "$robot_host" ] || usage; robot_host="$1" ;;
    esac
    shift
done
[ -n "$robot_host" ] || usage
# Files named on the command line are relative to where it was typed; the rest to the repository.
for name in binary model config; do
    [ -z "${!name}" ] || printf -v "$name" '%s' "$(realpath -m -- "${!name}")"
done
cd "$repository"
model="${model:-models/squeezenet-half-point.w8.onnx}"
config="${config:-deploy/relocd.toml}"
case "$robot" in v6|v5) ;; *) echo "--robot $robot: expected v6 or v5" >&2; exit 2 ;; esac
case "$after" in *[!A-Za-z0-9@._:-]*) echo "--after $after: not a unit name" >&2; exit 2 ;; esac
[[ "$robot_host" == *@* ]] || robot_host="nao@$robot_host"
dir=/home/nao/relocd
unit=/etc/systemd/system/relocd.service
# -n: fail with "a password is required" instead of waiting for one over a non-interactive ssh.
sudo="sudo -n "
[[ "$robot_host" != root@* ]] || sudo=""

# One word as a shell would need it typed: quoted only where it has to be.
quote() {
    case "$1" in
        '' | *[!A-Za-z0-9_./:@=,+-]*) printf "'%s'" "${1//\'/\'\\\'\'}" ;;
        *) printf '%s' "$1" ;;
    esac
}
# Prints a command (ready to paste into a shell), then runs it unless this is a dry run.
run() {
    printf '+'
    for word in "$@"; do printf ' %s' "$(quote "$word")"; done
    printf '\n'
    "$dry_run" || "$@"
}
# Runs a shell command line on the robot.
remote() { run ssh "$robot_host" "$1"; }

if "$uninstall"; then
    remote "${sudo}systemctl disable --now relocd.service || true"
    remote "${sudo}rm -rf $unit $unit.d && ${sudo}systemctl daemon-reload"
    remote "rm -f $dir/relocd $dir/model.onnx $dir/relocd.service"
    echo "relocd removed from $robot_host (kept: $dir/relocd.toml and any recordings in $dir)"
    exit 0
fi

for file in "$model" "$config" deploy/relocd.service ${binary:+"$binary"}; do
    [ -f "$file" ] || { echo "$file: no such file" >&2; exit 1; }
done
if [ -z "$binary" ]; then
    if "$dry_run"; then
        run deploy/build-nao.sh "$robot"
        triple=x86_64-unknown-linux-gnu
        [ "$robot" = v6 ] || triple=i686-unknown-linux-gnu
        binary="${CARGO_TARGET_DIR:-target}/$triple/nao/relocd"
    else
        printf '+ deploy/build-nao.sh %s\n' "$robot"
        binary="$(deploy/build-nao.sh "$robot")"
    fi
fi

remote "mkdir -p $dir"
run rsync -tp --chmod=F755 "$binary" "$robot_host:$dir/relocd"
run rsync -tp --chmod=F644 "$model" "$robot_host:$dir/model.onnx"
run rsync -tp --chmod=F644 deploy/relocd.service "$robot_host:$dir/relocd.service"
if "$replace_config"; then
    run rsync -tp --chmod=F644 "$config" "$robot_host:$dir/relocd.toml"
else
    run rsync -tp --chmod=F644 --ignore-existing "$config" "$robot_host:$dir/relocd.toml"
fi
# Installed as root, the files must still belong to nao, who runs relocd and edits its config.
[ -n "$sudo" ] || remote "chown -R nao:nao $dir"
remote "${sudo}install -m 0644 $dir/relocd.service $unit"
if [ -n "$after" ]; then
    remote "${sudo}mkdir -p $unit.d && printf '[Unit]\\nAfter=%s\\n' $after | ${sudo}tee $unit.d/after.conf >/dev/null"
fi
remote "${sudo}systemctl daemon-reload && ${sudo}systemctl enable relocd.service && ${sudo}systemctl restart relocd.service"
remote "systemctl --no-pager --lines=5 status relocd.service || true"
echo "relocd installed on $robot_host: journalctl -u relocd -f (on the robot) shows its log"
