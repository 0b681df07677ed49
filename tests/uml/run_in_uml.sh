#!/usr/bin/env bash
# Run one command inside user-mode Linux (UML) with real SocketCAN vcan0/vcan1 (SPEC section 6).
#
#   tests/uml/run_in_uml.sh [--timeout SEC] [--mem SIZE] [--keep] [--quiet] [--] CMD [ARG...]
#   tests/uml/run_in_uml.sh --probe        # boot, set up vcan0, run `true`: can UML run here?
#
# The host's root is the guest's root (hostfs), so the command sees the same files, Python and
# installed packages. The guest gets the caller's environment (PATH, PYTHONPATH, ...), working
# directory and LDE_IN_UML=1; `python...` as CMD is resolved to the interpreter's full path first.
# The guest's init (generated here) mounts proc, sys, a tmpfs for scratch ($TMPDIR) and /dev/shm,
# loads can, can-raw, can-dev, vcan from /usr/lib/uml/modules/<version>, creates vcan0 and vcan1,
# runs the command with stdin from /dev/null, writes its output and exit code to the host fs,
# syncs and halts. This script prints the command's output and returns its exit code.
#
# Exit codes: the command's; 77 = UML cannot run on this machine (reason on stderr, line starting
# "run_in_uml: SKIP:"); 124 = timed out; 125 = UML booted but the run broke (console tail shown).
# Environment: UML_KERNEL (default linux.uml), UML_TIMEOUT (s, default 900), UML_MEM (default 2G),
# UML_NO_SHIM=1 (do not use the xstate shim; for checking whether a host needs it),
# UML_SOFTIRQ_PRIO (SCHED_FIFO priority of the guest's ksoftirqd, default 99; 0 leaves it at the
# normal scheduler), LDE_UML_HOG=N (start N busy loops in the guest before CMD: a slow guest on
# purpose, to check that the tests skip with reasons instead of failing or hanging).
#
# Scheduling in the guest (UML runs everything on one CPU): real-time tasks may use at most 95 % of
# every second (sched_rt_runtime_us 950000 of 1000000, set explicitly), so normal tasks (pytest, the
# recorder thread) always progress; ksoftirqd runs at SCHED_FIFO UML_SOFTIRQ_PRIO because it delivers
# the vcan frames once the guest is busy (Linux 6.1 defers softirqs to it): at the normal scheduler
# the real-time service and simulator would wait for a thread they starve. docs/guide/bus.md, "User-mode Linux".
#
# Host quirks handled (found by trying; details in docs/guide/bus.md "User-mode Linux"):
# * XSAVE area larger than UML 6.1 supports (AMX hosts): the kernel panics at once with
#   "ptrace set fp regs failed, errno = 14". tests/uml/xstate_shim.c, LD_PRELOADed, fixes it
#   (needs a C compiler: cc/gcc).
# * stdin must not be the caller's terminal: UML's console takes it over (con0=fd:0,fd:1 gets
#   /dev/null here; the command's output goes to a file).
# * UML backs its RAM with a file in $TMPDIR or /dev/shm; a small /dev/shm (containers: 64 MB,
#   noexec) crashes it later with SIGBUS, so a disk directory is used when /dev/shm is too small.
# * The guest runs its init from the work directory: a noexec $TMPDIR makes the kernel panic
#   ("No working init found"), so the work directory goes where exec is allowed.
set -euo pipefail

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
EXIT_SKIP=77
EXIT_TIMEOUT=124
EXIT_BROKEN=125

timeout_s=${UML_TIMEOUT:-900}
softirq_prio=${UML_SOFTIRQ_PRIO:-99}
hogs=${LDE_UML_HOG:-0}
[[ $softirq_prio =~ ^[0-9]+$ && $softirq_prio -le 99 ]] || { echo "run_in_uml: UML_SOFTIRQ_PRIO=$softirq_prio: need 0..99" >&2; exit 2; }
[[ $hogs =~ ^[0-9]+$ ]] || { echo "run_in_uml: LDE_UML_HOG=$hogs: need a number of busy loops" >&2; exit 2; }
mem=${UML_MEM:-2G}
keep=0
quiet=0
probe=0

die_skip() { echo "run_in_uml: SKIP: $*" >&2; exit "$EXIT_SKIP"; }
note() { [[ $quiet == 1 ]] || echo "run_in_uml: $*" >&2; }

while [[ $# -gt 0 ]]; do
    case $1 in
        --timeout) timeout_s=$2; shift 2 ;;
        --mem) mem=$2; shift 2 ;;
        --keep) keep=1; shift ;;
        --quiet) quiet=1; shift ;;
        --probe) probe=1; shift ;;
        --) shift; break ;;
        -h|--help) sed -n '2,30p' "$0"; exit 0 ;;
        -*) echo "run_in_uml: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
if [[ $probe == 1 ]]; then
    set -- true
fi
if [[ $# -eq 0 ]]; then
    echo "usage: $0 [--timeout SEC] [--mem SIZE] [--keep] [--quiet] [--] CMD [ARG...] | --probe" >&2
    exit 2
fi

# --- can UML run here? ----------------------------------------------------------------------
[[ $(uname -s) == Linux ]] || die_skip "not Linux"
[[ $(uname -m) == x86_64 ]] || die_skip "user-mode Linux package is x86_64 only here ($(uname -m))"
kernel=${UML_KERNEL:-}
if [[ -z $kernel ]]; then
    kernel=$(command -v linux.uml || true)
fi
[[ -n $kernel && -x $kernel ]] || die_skip "no UML kernel (linux.uml); apt-get install user-mode-linux"
version=$("$kernel" --version 2>/dev/null | head -n1 | tr -d '[:space:]') || true
moddir=/usr/lib/uml/modules/$version/kernel
if [[ -z $version || ! -d $moddir ]]; then
    moddir=$(ls -d /usr/lib/uml/modules/*/kernel 2>/dev/null | tail -n1 || true)
fi
[[ -n $moddir && -d $moddir ]] || die_skip "no UML modules under /usr/lib/uml/modules"
modules=(net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko)
for m in "${modules[@]}"; do
    [[ -f $moddir/$m ]] || die_skip "UML module $moddir/$m missing (user-mode-linux without CAN?)"
done
insmod_bin=$(PATH=/usr/sbin:/sbin:$PATH command -v insmod || true)
ip_bin=$(PATH=/usr/sbin:/sbin:$PATH command -v ip || true)
[[ -n $insmod_bin ]] || die_skip "insmod not found; apt-get install kmod"
[[ -n $ip_bin ]] || die_skip "ip not found; apt-get install iproute2"
command -v timeout >/dev/null || die_skip "timeout (coreutils) not found"

# --- the command: resolve python to its full path -------------------------------------------
cmd0=$1
if [[ $cmd0 != */* ]]; then
    resolved=$(command -v "$cmd0" || true)
    [[ -n $resolved ]] || { echo "run_in_uml: command not found: $cmd0" >&2; exit 127; }
    if [[ $(basename "$cmd0") =~ ^python[0-9.]*$ ]]; then
        # pyenv shims and friends: ask the interpreter itself
        resolved=$("$resolved" -c 'import sys; print(sys.executable)')
    fi
    cmd0=$resolved
fi
shift
set -- "$cmd0" "$@"

# --- work directory (on the host fs, visible in the guest at the same path) -----------------
# it must allow exec (the guest runs its init from there): skip noexec mounts such as some /tmp
work=""
for base in "${TMPDIR:-/tmp}" /var/tmp "${XDG_CACHE_HOME:-$HOME/.cache}/lde-uml"; do
    mkdir -p "$base" 2>/dev/null || continue
    w=$(mktemp -d "$base/lde-uml.XXXXXX" 2>/dev/null) || continue
    printf '#!/bin/sh\nexit 0\n' > "$w/exec-check" && chmod +x "$w/exec-check"
    if "$w/exec-check" 2>/dev/null; then
        work=$(cd "$w" && pwd -P)
        break
    fi
    rm -rf "$w"
done
[[ -n $work ]] || die_skip "no writable directory that allows exec (tried \$TMPDIR, /var/tmp, ~/.cache)"
cleanup() {
    if [[ $keep == 1 ]]; then
        note "kept $work"
    else
        rm -rf "$work"
    fi
}
trap cleanup EXIT
mkdir -p "$work/scratch" "$work/umldir"

# --- the xstate shim (see xstate_shim.c) ----------------------------------------------------
preload=""
cc_bin=$(command -v cc || command -v gcc || true)
if [[ -n $cc_bin && -z ${UML_NO_SHIM:-} ]]; then
    if ! "$cc_bin" -shared -fPIC -O2 -o "$work/xstate_shim.so" "$HERE/xstate_shim.c" -ldl 2>"$work/cc.log"; then
        note "could not build the xstate shim: $(head -c 400 "$work/cc.log")"
    elif [[ -n $(env LD_PRELOAD="$work/xstate_shim.so" /bin/true 2>&1) ]]; then
        note "the xstate shim does not preload: $(env LD_PRELOAD="$work/xstate_shim.so" /bin/true 2>&1 | head -c 300)"
    else
        preload=$work/xstate_shim.so
    fi
fi

# --- where UML's RAM file goes: /dev/shm when it is big enough, else disk --------------------
mem_kb=$(numfmt --from=iec "${mem}" 2>/dev/null || echo 2147483648)
mem_kb=$((mem_kb / 1024))
shm_kb=$(df -Pk /dev/shm 2>/dev/null | awk 'NR==2 {print $4}' || true)
shm_noexec=$(awk '$2 == "/dev/shm" && $4 ~ /(^|,)noexec(,|$)/ {print "yes"}' /proc/mounts 2>/dev/null || true)
if [[ -n $shm_kb && $shm_kb -ge $mem_kb && -w /dev/shm && -z $shm_noexec ]]; then
    ramdir=/dev/shm
else
    ramdir=$work
    note "/dev/shm is missing, noexec or smaller than mem=$mem: UML's RAM file goes to $ramdir"
fi

# --- host mappings: UML maps guest memory into the host process of each guest process page
# range by page range, so a large guest process (python with numba: ~1 GB) needs far more than the
# default 65530 mappings: past vm.max_map_count it dies of SIGKILL with "UML ran out of memory on
# the host side" on the console (seen in .ci/run). Raise the limit when allowed (root), else say so.
want_maps=1048576
cur_maps=$(cat /proc/sys/vm/max_map_count 2>/dev/null || echo 0)
if [[ $cur_maps -lt $want_maps ]]; then
    if { echo "$want_maps" >/proc/sys/vm/max_map_count; } 2>/dev/null; then
        note "vm.max_map_count $cur_maps -> $want_maps (UML maps guest memory range by range)"
    else
        note "vm.max_map_count is $cur_maps and cannot be raised here: a large guest process may be killed" \
            "('UML ran out of memory on the host side'); as root: sysctl -w vm.max_map_count=$want_maps"
    fi
fi

# --- the guest's init ------------------------------------------------------------------------
guest_path=$(dirname "$cmd0"):$PATH:/usr/sbin:/usr/bin:/sbin:/bin
{
    echo '#!/bin/bash'
    echo '# generated by tests/uml/run_in_uml.sh: the init of one UML run'
    echo 'export PATH=/usr/sbin:/usr/bin:/sbin:/bin'
    printf 'W=%q\n' "$work"
    echo 'fail() { echo "$*" > "$W/setup_error"; sync; halt -f; }'
    echo 'mount -t proc proc /proc || fail "mount proc"'
    echo 'mount -t sysfs sysfs /sys || fail "mount sys"'
    echo 'mount -t tmpfs -o size=1g tmpfs "$W/scratch" || fail "mount scratch tmpfs"'
    echo 'mkdir -p /dev/shm && mount -t tmpfs -o size=512m tmpfs /dev/shm || fail "mount /dev/shm"'
    echo 'ip link set lo up'
    for m in "${modules[@]}"; do
        printf '%q %q >>"$W/setup.log" 2>&1 || fail "insmod %s: $(tail -n1 "$W/setup.log")"\n' \
            "$insmod_bin" "$moddir/$m" "$m"
    done
    for dev in vcan0 vcan1; do
        printf '%q link add dev %s type vcan >>"$W/setup.log" 2>&1 || fail "ip link add %s"\n' "$ip_bin" "$dev" "$dev"
        printf '%q link set up %s >>"$W/setup.log" 2>&1 || fail "ip link set up %s"\n' "$ip_bin" "$dev" "$dev"
    done
    echo 'echo 1000000 > /proc/sys/kernel/sched_rt_period_us; echo 950000 > /proc/sys/kernel/sched_rt_runtime_us'
    if [[ $softirq_prio -gt 0 ]]; then
        chrt_bin=$(PATH=/usr/sbin:/sbin:$PATH command -v chrt || true)
        [[ -n $chrt_bin ]] || die_skip "chrt not found (util-linux); needed for ksoftirqd's priority"
        printf 'for p in $(ls /proc | grep -E "^[0-9]+$"); do [ "$(cat /proc/$p/comm 2>/dev/null)" = ksoftirqd/0 ] && %q -f -p %d "$p" >>"$W/setup.log" 2>&1; done\n' \
            "$chrt_bin" "$softirq_prio"
    fi
    echo 'date +%s%N > "$W/t_ready"'
    # the caller's environment, minus what belongs to the host session or to UML itself
    while IFS= read -r -d '' kv; do
        name=${kv%%=*}
        value=${kv#*=}
        [[ $name =~ ^[A-Za-z_][A-Za-z0-9_]*$ ]] || continue
        case $name in
            PATH|PWD|OLDPWD|SHLVL|_|TMPDIR|LD_PRELOAD|TERM|DISPLAY|WAYLAND_DISPLAY|SSH_*|XDG_RUNTIME_DIR|MAIL|PS1) continue ;;
        esac
        printf 'export %s=%q\n' "$name" "$value"
    done < <(env -0)
    printf 'export PATH=%q\n' "$guest_path"
    echo 'export TMPDIR="$W/scratch" TERM=dumb LDE_IN_UML=1'
    printf 'cd %q || fail "cd %q"\n' "$PWD" "$PWD"
    for ((i = 0; i < hogs; i++)); do
        echo "sh -c 'while :; do :; done' </dev/null >/dev/null 2>&1 &  # LDE_UML_HOG"
    done
    printf '%q ' "$@"
    echo '</dev/null >"$W/output" 2>&1'
    echo 'echo $? > "$W/rc.tmp" && mv "$W/rc.tmp" "$W/rc"'
    echo 'sync'
    echo 'halt -f'
} > "$work/init"
chmod +x "$work/init"

# --- boot ------------------------------------------------------------------------------------
t_start=$(date +%s%N)
set +e
env ${preload:+LD_PRELOAD="$preload"} TMPDIR="$ramdir" \
    timeout -k 10 "$timeout_s" "$kernel" mem="$mem" rootfstype=hostfs rootflags=/ rw \
    init="$work/init" con=null con0=fd:0,fd:1 uml_dir="$work/umldir" umid=lde \
    </dev/null >"$work/console.log" 2>&1
uml_rc=$?
set -e
t_end=$(date +%s%N)

if [[ -f $work/t_ready ]]; then
    boot_ms=$(( ($(cat "$work/t_ready") - t_start) / 1000000 ))
    hog_note=""
    [[ $hogs -gt 0 ]] && hog_note="; $hogs busy loop(s) in the guest (LDE_UML_HOG)"
    note "boot to vcan0 ready: ${boot_ms} ms; whole run $(( (t_end - t_start) / 1000000 )) ms$hog_note"
fi
[[ -f $work/output ]] && cat "$work/output"

console_tail() { echo "--- UML console (last 25 lines) ---" >&2; tail -n 25 "$work/console.log" >&2 || true; }

if [[ -f $work/rc ]]; then
    rc=$(cat "$work/rc")
    if [[ $rc -ge 128 ]]; then  # killed by a signal inside the guest: say whether the OOM killer did it
        echo "run_in_uml: the command died of signal $((rc - 128)) inside the guest (mem=$mem)" >&2
        grep -iE "out of memory|killed process|oom-kill" "$work/console.log" | tail -n 5 >&2 || true
        if grep -q "ran out of memory on the host side" "$work/console.log"; then
            echo "run_in_uml: host mappings exhausted: vm.max_map_count is $(cat /proc/sys/vm/max_map_count)" >&2
        fi
    fi
    exit "$rc"
fi
if [[ $uml_rc == 124 || $uml_rc == 137 ]]; then
    echo "run_in_uml: timed out after ${timeout_s} s" >&2
    console_tail
    exit "$EXIT_TIMEOUT"
fi
if [[ -f $work/setup_error ]]; then
    echo "run_in_uml: guest setup failed: $(cat "$work/setup_error")" >&2
    console_tail
    exit "$EXIT_BROKEN"
fi
if grep -q "ptrace set fp regs failed" "$work/console.log"; then
    if [[ -z $preload ]]; then
        die_skip "this host's XSAVE area is larger than UML 6.1 handles and no C compiler (cc) is there to build tests/uml/xstate_shim.c (apt-get install gcc)"
    fi
    echo "run_in_uml: UML failed to restore FPU state even with the xstate shim" >&2
    console_tail
    exit "$EXIT_BROKEN"
fi
if grep -qE "check_ptrace|ptrace: Operation not permitted|PTRACE_[A-Z]+ failed" "$work/console.log"; then
    die_skip "UML cannot ptrace its processes here (container without ptrace?): $(grep -m1 -E 'ptrace' "$work/console.log")"
fi
if ! grep -q "Run $work/init as init process" "$work/console.log"; then
    die_skip "UML did not boot (exit $uml_rc): $(tail -n 3 "$work/console.log" | tr '\n' ' ')"
fi
echo "run_in_uml: UML ended (exit $uml_rc) without the command's exit code" >&2
console_tail
exit "$EXIT_BROKEN"
