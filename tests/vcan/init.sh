#!/bin/bash
# PID 1 of the User-Mode Linux guest started by run-in-vcan.sh.
#
# The guest's root is the host's root (hostfs), so every path below is a host
# path. The kernel command line hands over one variable, TECU_RUN: a private
# host directory written by run-in-vcan.sh that holds
#   env.sh    exports for the command (PATH, HOME, ...) and for this script:
#             TECU_CWD, TECU_UML_MODULES, TECU_TTY_OUT/ERR/SIZE
#   argv      the command, NUL-separated
# and receives
#   booted    written as soon as this script runs
#   rc        the command's exit status
#   tmp/      mount point for the guest's private TMPDIR (tmpfs)
# Guest console tty1 is the host's stdout, tty2 the host's stderr.

export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
umask 022
BUSYBOX=$(command -v busybox) || BUSYBOX=/bin/busybox

# True while a process other than PID 1 and the kernel threads is left.
others_alive() {
    local p c
    for p in /proc/[0-9]*; do
        [ "${p#/proc/}" = 1 ] && continue
        c=
        read -r -d "" c 2>/dev/null <"$p/cmdline"
        [ -n "$c" ] && return 0 # kernel threads and zombies have no cmdline
    done
    return 1
}

# wait_others TENTHS: wait up to TENTHS/10 s for the other processes to end.
wait_others() {
    local i
    for ((i = 0; i < $1; i++)); do
        others_alive || return 0
        sleep 0.1
    done
    return 1
}

finish() {
    local rc=$1
    exec 5>&- 6>&-
    # A short grace period for stray background processes and the console
    # relays to flush, then stop whatever is left.
    if ! wait_others 10; then
        kill -TERM -1 2>/dev/null
        wait_others 5 || kill -KILL -1 2>/dev/null
    fi
    [ -n "${TECU_RUN:-}" ] && echo "$rc" >"$TECU_RUN/rc"
    echo "$rc" >/proc/exitcode
    sync
    exec "$BUSYBOX" poweroff -f
}

fail() {
    echo "vcan guest: $*" >&2
    finish 125
}

mountpoint -q /proc || mount -t proc proc /proc
[ -n "${TECU_RUN:-}" ] && [ -d "$TECU_RUN" ] || fail "TECU_RUN is not set or not a directory"
: >"$TECU_RUN/booted"

exec </dev/null
[ -c /dev/tty2 ] && exec 2>/dev/tty2

mountpoint -q /sys || mount -t sysfs sysfs /sys
mountpoint -q /dev || mount -t devtmpfs devtmpfs /dev
mkdir -p /dev/pts /dev/shm
[ -e /dev/fd ] || ln -s /proc/self/fd /dev/fd
[ -e /dev/stdin ] || ln -s /proc/self/fd/0 /dev/stdin
[ -e /dev/stdout ] || ln -s /proc/self/fd/1 /dev/stdout
[ -e /dev/stderr ] || ln -s /proc/self/fd/2 /dev/stderr
mountpoint -q /dev/pts || mount -t devpts -o gid=5,mode=620,ptmxmode=666 devpts /dev/pts
mount -t tmpfs -o mode=1777 tmpfs /dev/shm || fail "cannot mount /dev/shm"
mount -t tmpfs -o mode=755 tmpfs /run || fail "cannot mount /run"
mount -t tmpfs -o mode=1777 tmpfs "$TECU_RUN/tmp" || fail "cannot mount the guest TMPDIR"
exec 2>/dev/tty2

# shellcheck source=/dev/null
. "$TECU_RUN/env.sh" || fail "cannot read $TECU_RUN/env.sh"

# A console wired to a host terminal behaves like one (UML puts the host's
# terminal in raw mode); one wired to a pipe or file passes bytes unchanged.
for n in 1 2; do
    if [ "$n" = 1 ]; then t=${TECU_TTY_OUT:-0}; else t=${TECU_TTY_ERR:-0}; fi
    if [ "$t" = 1 ]; then
        stty -F "/dev/tty$n" sane -echo 2>/dev/null
    else
        stty -F "/dev/tty$n" raw -echo 2>/dev/null
    fi
done

# CAN modules in dependency order (the list is written by setup-uml.sh).
[ -r "$TECU_UML_MODULES/modules.load" ] || fail "no module list in $TECU_UML_MODULES"
while read -r mod; do
    [ -n "$mod" ] || continue
    "$BUSYBOX" insmod "$TECU_UML_MODULES/$mod" || fail "insmod $mod failed"
done <"$TECU_UML_MODULES/modules.load"

ip link set lo up || fail "cannot bring up lo"
{ ip link add dev vcan0 type vcan && ip link set vcan0 up; } || fail "cannot create vcan0"

mapfile -d '' -t argv <"$TECU_RUN/argv"
[ "${#argv[@]}" -gt 0 ] || fail "no command given"
cd "$TECU_CWD" || fail "cannot cd to $TECU_CWD"

# Where the host's stdout/stderr is not a terminal, relay through a pipe so
# the command sees what it would see on the host.
if [ "${TECU_TTY_OUT:-0}" = 1 ]; then exec 5>/dev/tty1; else exec 5> >(exec cat >/dev/tty1); fi
if [ "${TECU_TTY_ERR:-0}" = 1 ]; then exec 6>/dev/tty2; else exec 6> >(exec cat >/dev/tty2); fi
# The window size is reset when a console is first opened: set it now.
if [ "${TECU_TTY_OUT:-0}" = 1 ] && [ -n "${TECU_TTY_SIZE:-}" ]; then
    stty rows "${TECU_TTY_SIZE% *}" cols "${TECU_TTY_SIZE#* }" <&5 2>/dev/null
fi
unset TECU_TTY_OUT TECU_TTY_ERR TECU_TTY_SIZE TECU_CWD TECU_UML_MODULES
export TECU_IN_VCAN_GUEST=1
export TMPDIR="$TECU_RUN/tmp"

"${argv[@]}" </dev/null >&5 2>&6 5>&- 6>&-
finish $?
