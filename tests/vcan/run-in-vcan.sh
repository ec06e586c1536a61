#!/bin/bash
# Run a command inside a User-Mode Linux guest that has SocketCAN and vcan0.
#
#   tests/vcan/run-in-vcan.sh CMD [ARGS...]
#
# The guest's root is the host's root, so CMD runs with the same cwd, PATH and
# files (e.g. the repo's .venv). Its stdout and stderr are streamed to ours and
# its exit status is returned. If the guest cannot start, this exits 125; if
# the whole run exceeds TECU_VCAN_TIMEOUT seconds, 124.
#
# Environment:
#   TECU_VCAN_TIMEOUT       limit for the whole run in seconds (default 3600)
#   TECU_VCAN_BOOT_TIMEOUT  seconds until the guest's init must be running (default 60)
#   TECU_VCAN_MEM           guest memory (default 2G)
#   TECU_VCAN_MODE          seccomp (default: try seccomp, then ptrace) or ptrace
#   TECU_VCAN_PASSENV       extra variable names to hand to CMD
#   TECU_VCAN_VERBOSE=1     print the guest kernel's console log afterwards
#   TECU_UML_CACHE          where setup-uml.sh keeps the kernel
set -uo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
export HOME=${HOME:-$(getent passwd "$(id -u)" | cut -d: -f6)}
CACHE=${TECU_UML_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/tractionecu-uml}
TOTAL=${TECU_VCAN_TIMEOUT:-3600}
BOOT_TIMEOUT=${TECU_VCAN_BOOT_TIMEOUT:-60}
MEM=${TECU_VCAN_MEM:-2G}

log() { echo "run-in-vcan: $*" >&2; }
die() { log "error: $*"; exit 125; }

[ $# -gt 0 ] || { echo "usage: $0 CMD [ARGS...]" >&2; exit 2; }

if [ ! -f "$CACHE/ok" ] || [ ! -x "$CACHE/bin/linux.uml" ] ||
    ! command -v busybox >/dev/null || ! command -v ip >/dev/null; then
    bash "$here/setup-uml.sh" || die "setup-uml.sh failed"
fi
UML=$CACHE/bin/linux.uml
INIT=$here/init.sh
[ -x "$INIT" ] || die "$INIT is not executable"

# The kernel command line cannot quote: paths on it must not contain blanks.
base=${TMPDIR:-/tmp}
case "$base" in /run | /run/* | /dev | /dev/* | /proc* | /sys*) base=/tmp ;; esac
run=$(mktemp -d "$base/tecu-vcan.XXXXXX") || die "cannot create a run directory"
for p in "$INIT" "$run" "$CACHE"; do
    case "$p" in *[[:space:]]*) rm -rf "$run"; die "path contains blanks: $p" ;; esac
done
mkdir "$run/tmp" "$run/uml"

tty_state=
if [ -t 1 ]; then { tty_state=$(stty -g <&3 2>/dev/null); } 3>&1; fi
uml_pid=
cleanup() {
    if [ -n "$uml_pid" ]; then kill "$uml_pid" 2>/dev/null; wait "$uml_pid" 2>/dev/null; fi
    if [ -n "$tty_state" ]; then stty "$tty_state" <&1 2>/dev/null; fi
    rm -rf "$run"
}
trap cleanup EXIT
trap 'log "interrupted"; exit 130' INT TERM HUP

# What CMD gets: cwd, PATH, a chosen set of the caller's variables, and
# whether our stdout/stderr are terminals.
tty_out='' tty_err='' tty_size=''
if [ -t 1 ]; then tty_out=1; { tty_size=$(stty size <&3 2>/dev/null); } 3>&1; fi
if [ -t 2 ]; then tty_err=1; fi
{
    printf 'export TECU_CWD=%q\n' "$PWD"
    printf 'export TECU_UML_MODULES=%q\n' "$CACHE/modules"
    if [ -n "$tty_out" ]; then
        echo 'export TECU_TTY_OUT=1'
        case "$tty_size" in [1-9]*" "[1-9]*) echo "export TECU_TTY_SIZE='$tty_size'" ;; esac
    fi
    if [ -n "$tty_err" ]; then echo 'export TECU_TTY_ERR=1'; fi
    for v in $(compgen -e); do
        case "$v" in
            PATH | HOME | USER | LOGNAME | SHELL | LANG | LANGUAGE | LC_* | TERM | TZ | COLUMNS | \
                VIRTUAL_ENV | PYTHON* | PIP_* | PYTEST_* | HYPOTHESIS_* | CI | NO_COLOR | FORCE_COLOR | \
                TECU_*) ;;
            *) case " ${TECU_VCAN_PASSENV:-} " in *" $v "*) ;; *) continue ;; esac ;;
        esac
        case "$v" in TECU_RUN | TECU_CWD | TECU_UML_MODULES | TECU_TTY_* | TECU_IN_VCAN_GUEST) continue ;; esac
        printf 'export %s=%q\n' "$v" "${!v}"
    done
} >"$run/env.sh"
printf '%s\0' "$@" >"$run/argv"

now_ms() { local t=${EPOCHREALTIME/[.,]/}; echo $((t / 1000)); }

# boot MODE: start the guest; returns 0 if its init ran, 1 if it never started.
boot() {
    local mode=$1 start opts=()
    [ "$mode" = seccomp ] && opts=(seccomp=on)
    rm -f "$run/booted" "$run/rc"
    start=$(now_ms)
    timeout -k 5 "$TOTAL" "$UML" mem="$MEM" quiet "${opts[@]}" \
        root=/dev/root rootfstype=hostfs rootflags=/ rw init="$INIT" \
        con=null ssl=null con0=null,fd:1 con1=null,fd:3 con2=null,fd:4 \
        umid="tecu-$$-$mode" uml_dir="$run/uml" TECU_RUN="$run" \
        </dev/null 3>&1 4>&2 >"$run/console-$mode.log" &
    uml_pid=$!
    while [ ! -e "$run/booted" ] && kill -0 "$uml_pid" 2>/dev/null; do
        if [ $(($(now_ms) - start)) -gt $((BOOT_TIMEOUT * 1000)) ]; then
            log "guest ($mode) did not start within ${BOOT_TIMEOUT}s"
            kill "$uml_pid" 2>/dev/null
            break
        fi
        sleep 0.02
    done
    [ -e "$run/booted" ] && [ -n "${TECU_VCAN_VERBOSE:-}" ] &&
        log "guest ($mode) init started after $(($(now_ms) - start)) ms"
    wait "$uml_pid"
    uml_rc=$?
    elapsed_ms=$(($(now_ms) - start))
    uml_pid=
    if [ -n "$tty_state" ]; then stty "$tty_state" <&1 2>/dev/null; fi
    [ -e "$run/booted" ]
}

show_console() {
    local f=$run/console-$1.log
    [ -s "$f" ] || return 0
    log "guest kernel console ($1):"
    sed 's/^/  | /' "$f" >&2
}

mode=${TECU_VCAN_MODE:-seccomp}
if ! boot "$mode"; then
    show_console "$mode"
    [ "$mode" = seccomp ] || die "the guest did not start"
    log "the guest did not start with seccomp=on (status $uml_rc); trying ptrace mode"
    mode=ptrace
    boot ptrace || { show_console ptrace; die "the guest did not start (status $uml_rc)"; }
fi
[ -n "${TECU_VCAN_VERBOSE:-}" ] && show_console "$mode"

if [ ! -s "$run/rc" ]; then
    show_console "$mode"
    if [ "$uml_rc" = 124 ] || { [ "$uml_rc" = 137 ] && [ "$elapsed_ms" -ge $((TOTAL * 1000)) ]; }; then
        log "error: timed out after ${TOTAL}s"
        exit 124
    fi
    die "the guest stopped before the command finished (status $uml_rc)"
fi
rc=$(cat "$run/rc")
exit "$rc"
