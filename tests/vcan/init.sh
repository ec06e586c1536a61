#!/bin/bash
# PID 1 of the User-Mode Linux guest started by run-in-vcan.sh.
#
# The guest's root is the host's root (hostfs), so every path below is a host
# path. The kernel command line hands over one variable, TECU_RUN: a private
# host directory written by run-in-vcan.sh that holds
#   env.sh    exports for the command (PATH, HOME, TECU_CWD, TECU_UML_MODULES, ...)
#   argv      the command, NUL-separated
# and receives
#   booted    written as soon as this script runs
#   rc        the command's exit status
#   tmp/      mount point for the guest's private TMPDIR (tmpfs)

export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
umask 022

fail() {
    echo "vcan guest: $*" >&2
    finish 125
}

finish() {
    local rc=$1
    # Give stray background processes a moment, then stop them.
    kill -TERM -1 2>/dev/null
    local i p c alive
    for i in 1 2 3 4 5 6 7 8 9 10; do
        alive=
        for p in /proc/[0-9]*; do
            [ "${p#/proc/}" = 1 ] && continue
            c=
            read -r -d "" c 2>/dev/null <"$p/cmdline"
            [ -n "$c" ] && { alive=1; break; } # kernel threads have no cmdline
        done
        [ -z "$alive" ] && break
        sleep 0.1
    done
    kill -KILL -1 2>/dev/null
    [ -n "$TECU_RUN" ] && echo "$rc" >"$TECU_RUN/rc"
    echo "$rc" >/proc/exitcode
    sync
    exec "$BUSYBOX" poweroff -f
}

BUSYBOX=$(command -v busybox) || BUSYBOX=/bin/busybox

mountpoint -q /proc || mount -t proc proc /proc
[ -n "$TECU_RUN" ] && [ -d "$TECU_RUN" ] || fail "TECU_RUN is not set or not a directory"
: >"$TECU_RUN/booted"

# Guest consoles wired to the host's stdout (tty1) and stderr (tty2).
exec </dev/null
if [ -c /dev/tty2 ]; then exec 2>/dev/tty2; fi

mountpoint -q /sys || mount -t sysfs sysfs /sys
mountpoint -q /dev || mount -t devtmpfs devtmpfs /dev
mkdir -p /dev/pts /dev/shm
mountpoint -q /dev/pts || mount -t devpts -o gid=5,mode=620,ptmxmode=666 devpts /dev/pts
mount -t tmpfs -o mode=1777 tmpfs /dev/shm || fail "cannot mount /dev/shm"
mount -t tmpfs -o mode=755 tmpfs /run || fail "cannot mount /run"
mount -t tmpfs -o mode=1777 tmpfs "$TECU_RUN/tmp" || fail "cannot mount the guest TMPDIR"
# Consoles must not turn \n into \r\n.
stty -F /dev/tty1 raw -echo 2>/dev/null
stty -F /dev/tty2 raw -echo 2>/dev/null
exec 2>/dev/tty2

# shellcheck source=/dev/null
. "$TECU_RUN/env.sh" || fail "cannot read $TECU_RUN/env.sh"

# CAN modules in dependency order (the list is written by setup-uml.sh).
[ -r "$TECU_UML_MODULES/modules.load" ] || fail "no module list in $TECU_UML_MODULES"
while read -r mod; do
    [ -n "$mod" ] || continue
    "$BUSYBOX" insmod "$TECU_UML_MODULES/$mod" || fail "insmod $mod failed"
done <"$TECU_UML_MODULES/modules.load"

ip link set lo up || fail "cannot bring up lo"
{ ip link add dev vcan0 type vcan && ip link set vcan0 up; } || fail "cannot create vcan0"

export TECU_IN_VCAN_GUEST=1
export TMPDIR="$TECU_RUN/tmp"
mapfile -d '' -t argv <"$TECU_RUN/argv"
[ "${#argv[@]}" -gt 0 ] || fail "no command given"

cd "$TECU_CWD" || fail "cannot cd to $TECU_CWD"
"${argv[@]}" </dev/null >/dev/tty1 2>/dev/tty2
finish $?
