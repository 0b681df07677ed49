/*
 * LD_PRELOAD shim for Debian's user-mode Linux 6.1 (linux.uml) on hosts with a large XSAVE area.
 *
 * Why: UML 6.1 saves and restores its processes' FPU/vector state with
 * ptrace(PTRACE_GETREGSET/PTRACE_SETREGSET, NT_X86_XSTATE) into a buffer of a size fixed when the
 * kernel was built (2696 bytes: up to AVX-512 and PKRU). The host kernel accepts a SETREGSET of
 * NT_X86_XSTATE only with its *whole* XSAVE size (arch/x86/kernel/fpu/regset.c, xstateregs_set:
 * "count != fpu_user_cfg.max_size -> -EFAULT"). On a host with AMX (Sapphire Rapids and later:
 * 11008 bytes) every SETREGSET fails and UML panics at once:
 *     userspace - ptrace set fp regs failed, errno = 14
 *     Kernel panic - not syncing: Attempted to kill init! exitcode=0x0000000b
 * Upstream fixed it later (UML learned the host's xstate size at run time); 6.1 did not get it.
 *
 * What: wrap libc's ptrace(). For NT_X86_XSTATE requests whose buffer is smaller than the host's
 * XSAVE area, read the whole area into a bounce buffer; GETREGSET copies UML's part out of it,
 * SETREGSET overlays UML's part on the current whole area and writes the whole area. The state
 * beyond UML's buffer (AMX tiles, unused by UML processes) is kept as it is. With a host area no
 * larger than UML's buffer every call passes straight through.
 *
 * (Forcing UML back to PTRACE_GETFPREGS instead is not safe: the upper halves of the vector
 * registers are then lost on every page fault, because the host resets them for UML's SIGSEGV
 * stub handler; glibc's AVX string functions then return garbage inside UML.)
 *
 * Build: cc -shared -fPIC -O2 -o xstate_shim.so xstate_shim.c -ldl   (tests/uml/run_in_uml.sh does)
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdarg.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

#ifndef NT_X86_XSTATE
#define NT_X86_XSTATE 0x202
#endif

#define BOUNCE_SIZE 65536 /* larger than any x86 XSAVE area so far (AMX: 11008 bytes) */

typedef long (*ptrace_fn)(int, ...);

static __thread unsigned char bounce[BOUNCE_SIZE] __attribute__((aligned(64)));

long ptrace(enum __ptrace_request request, ...)
{
    static ptrace_fn real_ptrace;
    va_list ap;
    pid_t pid;
    void *addr;
    void *data;

    va_start(ap, request);
    pid = va_arg(ap, pid_t);
    addr = va_arg(ap, void *);
    data = va_arg(ap, void *);
    va_end(ap);

    if (!real_ptrace)
        real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");

    if ((request == PTRACE_GETREGSET || request == PTRACE_SETREGSET) && (long)addr == NT_X86_XSTATE &&
        data != NULL) {
        struct iovec *iov = data;
        struct iovec whole = {bounce, BOUNCE_SIZE};

        if (real_ptrace(PTRACE_GETREGSET, pid, addr, &whole) < 0 || whole.iov_len <= iov->iov_len)
            return real_ptrace(request, pid, addr, data); /* host area fits: pass through */
        if (request == PTRACE_GETREGSET) {
            memcpy(iov->iov_base, bounce, iov->iov_len);
            return 0;
        }
        memcpy(bounce, iov->iov_base, iov->iov_len);
        return real_ptrace(PTRACE_SETREGSET, pid, addr, &whole);
    }
    return real_ptrace(request, pid, addr, data);
}
