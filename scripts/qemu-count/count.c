/* Counts the guest instructions QEMU executes, exactly, and reports the count at marks.
 *
 * Every instruction adds one to a counter (an inline add QEMU emits before the instruction, so
 * the count is exact even when a block of translated code is left early). Arguments (each
 * `name=value` after the plugin's path in `-plugin`):
 *   begin=ADDR   the address of the guest's `mpo_mark_begin` (its symbol's value)
 *   end=ADDR     the address of `mpo_mark_end`
 *   histogram=1  also count, per instruction address, the executions between a `begin` and the
 *                next `end` (a callback per instruction: slower), written at exit
 * Whenever the instruction at a mark's address executes, a line `B <count>` or `E <count>` is
 * written (the count of instructions executed before it); at exit, `total <count>` and, with
 * the histogram, one line `H <address in hex> <executions>` per instruction executed in a span.
 * Output goes through QEMU's log: run with `-d plugin -D FILE`; "at exit" means a clean exit
 * (the guest's, or QMP's `quit`), not a kill. A span's count, the difference of its `E` and
 * `B` lines, includes three instructions of the marks themselves (`mpo_mark_begin`'s `nop` and
 * return, and the call to `mpo_mark_end`).
 *
 * Build: gcc -shared -fPIC -O2 -o libqemu-count.so count.c   (scripts/setup-cortex-m) */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "qemu-plugin-v1.h"

QEMU_PLUGIN_EXPORT int qemu_plugin_version = 1;

static uint64_t executed;
static uint64_t mark_begin = UINT64_MAX, mark_end = UINT64_MAX;

/* The histogram: executions in spans, per halfword address of the first 4 MiB (the board's
 * code memory). */
#define CODE_HALFWORDS (4u << 20 >> 1)
static uint64_t *histogram;
static int in_span;

static void report(const char *what, uint64_t count)
{
    char line[64];
    snprintf(line, sizeof line, "%s %" PRIu64 "\n", what, count);
    qemu_plugin_outs(line);
}

static void on_begin(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    (void)udata;
    report("B", executed);
    in_span = 1;
}

static void on_end(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    (void)udata;
    report("E", executed);
    in_span = 0;
}

static void on_insn(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    if (in_span) {
        histogram[(uintptr_t)udata]++;
    }
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t at = qemu_plugin_insn_vaddr(insn);
        if (at == mark_begin) {
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_begin, QEMU_PLUGIN_CB_NO_REGS, NULL);
        } else if (at == mark_end) {
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_end, QEMU_PLUGIN_CB_NO_REGS, NULL);
        }
        if (histogram && at / 2 < CODE_HALFWORDS) {
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_insn, QEMU_PLUGIN_CB_NO_REGS,
                                                   (void *)(uintptr_t)(at / 2));
        }
        qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, &executed, 1);
    }
}

static void at_exit(qemu_plugin_id_t id, void *udata)
{
    (void)id;
    (void)udata;
    report("total", executed);
    if (!histogram) {
        return;
    }
    char line[64];
    for (uint32_t h = 0; h < CODE_HALFWORDS; h++) {
        if (histogram[h]) {
            snprintf(line, sizeof line, "H %" PRIx32 " %" PRIu64 "\n", h * 2, histogram[h]);
            qemu_plugin_outs(line);
        }
    }
}

/* `name=value`: the value, or NULL for another name. */
static const char *value_of(const char *arg, const char *name)
{
    size_t len = strlen(name);
    return strncmp(arg, name, len) == 0 && arg[len] == '=' ? arg + len + 1 : NULL;
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                           int argc, char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++) {
        const char *v;
        /* Thumb symbols have bit 0 set; instructions are at even addresses. */
        if ((v = value_of(argv[i], "begin"))) {
            mark_begin = strtoull(v, NULL, 0) & ~(uint64_t)1;
        } else if ((v = value_of(argv[i], "end"))) {
            mark_end = strtoull(v, NULL, 0) & ~(uint64_t)1;
        } else if ((v = value_of(argv[i], "histogram")) && strcmp(v, "1") == 0) {
            histogram = calloc(CODE_HALFWORDS, sizeof *histogram);
            if (!histogram) {
                return -1;
            }
        } else {
            fprintf(stderr, "qemu-count: unknown argument %s\n", argv[i]);
            return -1;
        }
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
