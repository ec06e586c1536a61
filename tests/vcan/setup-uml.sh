#!/bin/bash
# Prepare the User-Mode Linux (UML) kernel that run-in-vcan.sh boots.
#
# Idempotent. It
#   1. installs the host packages the guest and the tests use
#      (patchelf, busybox-static, iproute2, can-utils);
#   2. downloads Debian sid's user-mode-linux and libc6 packages with a
#      private apt state (own sources.list, lists and cache directories),
#      leaving the system's apt configuration untouched;
#   3. unpacks them, points linux.uml at the unpacked loader and libc,
#      keeps only the CAN kernel modules and writes their load order;
#   4. caches the result, so later runs return at once.
#
# Cache directory: $TECU_UML_CACHE, else $XDG_CACHE_HOME/tractionecu-uml,
# else ~/.cache/tractionecu-uml.
#
# Environment:
#   TECU_UML_CACHE       cache directory (see above)
#   TECU_DEBIAN_MIRROR   Debian archive URI; default: the one the system's
#                        apt sources already use
#   TECU_UML_SUITE       suite to take the kernel from (default: sid)
#
# Options: --force rebuilds the cache; --print-cache prints its path.
set -euo pipefail

CAN_MODULES=(can can-raw can-bcm can-gw can-j1939 can-dev vcan vxcan)
HOST_PACKAGES=(patchelf busybox-static iproute2 can-utils)
SUITE=${TECU_UML_SUITE:-sid}
export HOME=${HOME:-$(getent passwd "$(id -u)" | cut -d: -f6)}
CACHE=${TECU_UML_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/tractionecu-uml}
FORMAT=1 # bump when the cache layout changes

log() { echo "setup-uml: $*" >&2; }
die() { log "error: $*"; exit 1; }

force=
case "${1:-}" in
    --force) force=1 ;;
    --print-cache) echo "$CACHE"; exit 0 ;;
    "") ;;
    *) die "usage: $0 [--force|--print-cache]" ;;
esac

as_root() {
    if [ "$(id -u)" = 0 ]; then "$@"
    elif command -v sudo >/dev/null; then sudo "$@"
    else die "need root to run: $*"
    fi
}

install_host_packages() {
    local missing=() p
    for p in "${HOST_PACKAGES[@]}"; do
        dpkg-query -W -f='${db:Status-Status}' "$p" 2>/dev/null | grep -qx installed || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    log "installing host packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    if ! as_root apt-get install -y -q --no-install-recommends "${missing[@]}" >&2; then
        as_root apt-get update -q >&2
        as_root apt-get install -y -q --no-install-recommends "${missing[@]}" >&2
    fi
}

# Print "URI KEYRING" of the first enabled Debian archive source (not the
# security archive) configured for the system's apt.
find_mirror() {
    local codename files f
    codename=$(. /etc/os-release 2>/dev/null && echo "${VERSION_CODENAME:-}")
    files=()
    [ -f /etc/apt/sources.list ] && files+=(/etc/apt/sources.list)
    for f in /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
        [ -f "$f" ] && files+=("$f")
    done
    [ ${#files[@]} -gt 0 ] || return 1
    awk -v codename="$codename" '
        function debian_suite(s) {
            sub(/-(updates|backports|proposed-updates)$/, "", s)
            return s == codename || s ~ /^(stable|testing|unstable|sid|oldstable)$/
        }
        function consider(types, uri, suites, key,   n, i, a) {
            if (found || types !~ /(^|[ \t])deb([ \t]|$)/ || uri == "" || uri ~ /security/) return
            n = split(suites, a, /[ \t]+/)
            for (i = 1; i <= n; i++) if (a[i] != "" && debian_suite(a[i])) {
                found = 1; print uri, (key == "" ? "-" : key); return
            }
        }
        function flush() {
            if (inblock && enabled != "no") consider(types, uri, suites, key)
            inblock = 0; types = uri = suites = key = enabled = ""
        }
        FILENAME ~ /\.sources$/ {
            if (FILENAME != last) { flush(); last = FILENAME }
            if ($0 ~ /^[ \t]*$/) { flush(); next }
            if ($0 ~ /^#/) next
            inblock = 1
            field = tolower($1); sub(/:$/, "", field); $1 = ""; sub(/^[ \t]+/, "")
            if (field == "types") types = $0
            else if (field == "uris") { split($0, u, /[ \t]+/); uri = u[1] }
            else if (field == "suites") suites = $0
            else if (field == "signed-by" && $0 ~ /^\//) key = $0
            else if (field == "enabled") enabled = tolower($0)
            next
        }
        {
            flush(); last = FILENAME
            line = $0; sub(/#.*/, "", line)
            if (line !~ /^[ \t]*deb[ \t]/) next
            key = ""
            if (match(line, /\[[^]]*\]/)) {
                opts = substr(line, RSTART + 1, RLENGTH - 2)
                line = substr(line, 1, RSTART - 1) substr(line, RSTART + RLENGTH)
                if (match(opts, /signed-by=[^ \t]+/)) key = substr(opts, RSTART + 10, RLENGTH - 10)
            }
            n = split(line, w, /[ \t]+/)
            i = (w[1] == "" ? 2 : 1)
            consider("deb", w[i + 1], w[i + 2], key)
        }
        END { flush() }
    ' "${files[@]}"
}

cache_ok() {
    [ -f "$CACHE/ok" ] && [ "$(cat "$CACHE/ok")" = "$FORMAT" ] &&
        [ -x "$CACHE/bin/linux.uml" ] && [ -f "$CACHE/modules/modules.load" ]
}

install_host_packages

mkdir -p "$(dirname "$CACHE")"
exec 9>"$CACHE.lock"
flock 9

if [ -z "$force" ] && cache_ok; then
    exit 0
fi

if [ -n "${TECU_DEBIAN_MIRROR:-}" ]; then
    mirror=$TECU_DEBIAN_MIRROR keyring=-
else
    read -r mirror keyring < <(find_mirror || true) || true
    [ -n "${mirror:-}" ] || die "no Debian archive found in /etc/apt/sources.list*; set TECU_DEBIAN_MIRROR"
fi
if [ "$keyring" = - ] || [ ! -r "$keyring" ]; then
    keyring=/usr/share/keyrings/debian-archive-keyring.gpg
fi
[ -r "$keyring" ] || die "no Debian archive keyring at $keyring"
log "fetching user-mode-linux and libc6 from $mirror ($SUITE)"

stage="$CACHE.new.$$"
rm -rf "$stage"
trap 'rm -rf "$stage"' EXIT
apt_dir="$stage/apt"
mkdir -p "$apt_dir"/{lists/partial,cache/archives/partial,state,sources.list.d,preferences.d} \
    "$stage"/{debs,root,bin,lib,modules}
: >"$apt_dir/state/status"
echo "deb [signed-by=$keyring] $mirror $SUITE main" >"$apt_dir/sources.list"
apt_opts=(
    -o "Dir::Etc::SourceList=$apt_dir/sources.list"
    -o "Dir::Etc::SourceParts=$apt_dir/sources.list.d"
    -o "Dir::Etc::Preferences=$apt_dir/preferences"
    -o "Dir::Etc::PreferencesParts=$apt_dir/preferences.d"
    -o "Dir::State=$apt_dir/state"
    -o "Dir::State::Lists=$apt_dir/lists"
    -o "Dir::State::status=$apt_dir/state/status"
    -o "Dir::Cache=$apt_dir/cache"
    -o "Acquire::Languages=none"
    -o "APT::Architectures::=amd64"
    -o "APT::Sandbox::User=$(id -un)"
)
[ "$(dpkg --print-architecture)" = amd64 ] || die "only amd64 hosts are supported"
apt-get "${apt_opts[@]}" -q update >&2
(cd "$stage/debs" && apt-get "${apt_opts[@]}" -q download user-mode-linux libc6 >&2)
for deb in "$stage"/debs/*.deb; do
    dpkg -x "$deb" "$stage/root"
done

# Kernel binary, run by the unpacked glibc (the host's may be too old).
cp "$stage/root/usr/bin/linux.uml" "$stage/bin/linux.uml"
libdir="$stage/root/usr/lib/x86_64-linux-gnu"
cp -L "$libdir/ld-linux-x86-64.so.2" "$libdir/libc.so.6" "$stage/lib/"
for lib in $(patchelf --print-needed "$stage/bin/linux.uml"); do
    [ -e "$stage/lib/$lib" ] || cp -L "$libdir/$lib" "$stage/lib/" || die "missing library $lib"
done
patchelf --set-interpreter "$CACHE/lib/ld-linux-x86-64.so.2" --set-rpath "$CACHE/lib" \
    "$stage/bin/linux.uml"

# CAN modules only, with their dependencies, in load order.
moddir=$(find "$stage/root/usr/lib/uml/modules" -mindepth 1 -maxdepth 1 -type d | head -n 1)
[ -n "$moddir" ] && [ -f "$moddir/modules.dep" ] || die "no modules in the user-mode-linux package"
declare -A loaded=()
order=()
add_module() { # $1: path relative to $moddir
    local rel=$1 dep
    [ -n "${loaded[$rel]:-}" ] && return 0
    loaded[$rel]=1
    for dep in $(awk -v m="$rel:" '$1 == m { $1 = ""; print }' "$moddir/modules.dep"); do
        add_module "$dep"
    done
    order+=("$rel")
}
for name in "${CAN_MODULES[@]}"; do
    rel=$(awk -F: -v n="$name" '{ f = $1; sub(/.*\//, "", f) } f == n ".ko" || f ~ "^" n "\\.ko\\." { print $1; exit }' "$moddir/modules.dep")
    [ -n "$rel" ] || die "module $name not in the user-mode-linux package"
    add_module "$rel"
done
: >"$stage/modules/modules.load"
for rel in "${order[@]}"; do
    base=${rel##*/}
    case "$base" in
        *.ko.xz) xz -dc "$moddir/$rel" >"$stage/modules/${base%.xz}"; base=${base%.xz} ;;
        *.ko.zst) zstd -qdc "$moddir/$rel" >"$stage/modules/${base%.zst}"; base=${base%.zst} ;;
        *.ko.gz) gzip -dc "$moddir/$rel" >"$stage/modules/${base%.gz}"; base=${base%.gz} ;;
        *) cp "$moddir/$rel" "$stage/modules/$base" ;;
    esac
    echo "$base" >>"$stage/modules/modules.load"
done

{
    echo "suite=$SUITE"
    echo "mirror=$mirror"
    for deb in "$stage"/debs/*.deb; do
        echo "$(dpkg-deb -f "$deb" Package)=$(dpkg-deb -f "$deb" Version)"
    done
    echo "kernel=${moddir##*/}"
} >"$stage/VERSION"
rm -rf "$apt_dir" "$stage/debs" "$stage/root"
echo "$FORMAT" >"$stage/ok"

rm -rf "$CACHE"
mv "$stage" "$CACHE"
trap - EXIT
"$CACHE/bin/linux.uml" --version >/dev/null || die "the patched linux.uml does not run"
log "ready in $CACHE ($(du -sh "$CACHE" | cut -f1)): $(tr '\n' ' ' <"$CACHE/VERSION")"
