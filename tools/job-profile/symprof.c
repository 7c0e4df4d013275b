/* symprof: executed instructions per address of the firmware image (the first 1 MB of the
 * address space), for tools/job-profile/attribute.py to attribute to source functions.
 *
 * qemu-system-arm ... -plugin ./libsymprof.so,out=FILE[,on=SYM,off=SYM]
 *
 * FILE is rewritten every second and at exit (QEMU may be killed rather than exit): one line
 * "0xADDR COUNT" per executed address. With on=SYM,off=SYM only what runs between a call of
 * `on` and the next call of `off` is counted (the firmware's measured regions:
 * strata_counted_on/off; a callback per instruction, slower than the default inline count).
 * With keep=SYM as well, a region counts only when `keep` is called after its `off` and
 * before the next `on` (the firmware keeps the regions its figures count). With isr=SYM the
 * instructions between that handler's entry and its return (a `pop {..., pc}` or `bx lr`
 * inside the symbol; the handler must not tail-call) are left out: thread mode only.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <unistd.h>
#include "qemu-plugin-v1.h"

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

/* Per-halfword counts over the first 1 MB of the address space. */
#define PCS (1u << 19)
static uint64_t pcs[PCS];
static const char *out_path;

static const char *on_name, *off_name, *keep_name, *isr_name;
static uint64_t on_addr = ~0ull, off_addr = ~0ull, keep_addr = ~0ull, isr_addr = ~0ull;
static int recording, in_isr;

/* The current region's counts (committed into pcs when kept) and the addresses it touched. */
static uint32_t cur[PCS];
static uint32_t *touched;
static size_t n_touched, cap_touched;

static void commit(void) {
    for (size_t i = 0; i < n_touched; i++) {
        pcs[touched[i]] += cur[touched[i]];
        cur[touched[i]] = 0;
    }
    n_touched = 0;
}
static void discard(void) {
    for (size_t i = 0; i < n_touched; i++) cur[touched[i]] = 0;
    n_touched = 0;
}
static void set_on(unsigned int vcpu, void *u) {
    discard(); /* a region not kept */
    recording = 1;
}
static void set_off(unsigned int vcpu, void *u) {
    recording = 0;
    if (!keep_name) commit();
}
static void keep(unsigned int vcpu, void *u) { commit(); }
static void isr_enter(unsigned int vcpu, void *u) { in_isr = 1; }
static void isr_leave(unsigned int vcpu, void *u) { in_isr = 0; }
static void count_if_on(unsigned int vcpu, void *u) {
    if (!recording || in_isr) return;
    uint32_t i = (uint32_t)(uintptr_t)u;
    if (cur[i]++ == 0) {
        if (n_touched == cap_touched) {
            cap_touched = cap_touched ? 2 * cap_touched : 4096;
            touched = realloc(touched, cap_touched * sizeof *touched);
            if (!touched) abort();
        }
        touched[n_touched++] = i;
    }
}

/* A return from the handler: `pop {..., pc}`, `ldm ... {..., pc}` or `bx lr`. */
static int is_return(const char *d) {
    return d && ((strstr(d, "pop") && strstr(d, "pc}")) || (strstr(d, "ldm") && strstr(d, "pc}")) ||
                 strstr(d, "bx lr"));
}

static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t va = qemu_plugin_insn_vaddr(insn);
        const char *s = qemu_plugin_insn_symbol(insn);
        /* A marker's entry: the first time a block starts inside the named symbol. */
        if (on_name && i == 0 && s) {
            if (on_addr == ~0ull && !strcmp(s, on_name)) on_addr = va;
            if (off_addr == ~0ull && !strcmp(s, off_name)) off_addr = va;
            if (keep_name && keep_addr == ~0ull && !strcmp(s, keep_name)) keep_addr = va;
            if (isr_name && isr_addr == ~0ull && !strcmp(s, isr_name)) isr_addr = va;
        }
        if (va == on_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, set_on, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == off_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, set_off, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == keep_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, keep, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == isr_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, isr_enter, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va / 2 >= PCS) continue;
        if (on_name)
            qemu_plugin_register_vcpu_insn_exec_cb(insn, count_if_on, QEMU_PLUGIN_CB_NO_REGS,
                                                   (void *)(uintptr_t)(va / 2));
        else
            qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, &pcs[va / 2], 1);
        /* After the count: the return instruction itself is the handler's. */
        if (isr_name && s && !strcmp(s, isr_name)) {
            char *d = qemu_plugin_insn_disas(insn);
            if (is_return(d))
                qemu_plugin_register_vcpu_insn_exec_cb(insn, isr_leave, QEMU_PLUGIN_CB_NO_REGS, NULL);
            free(d);
        }
    }
}

/* Writes the counts to out_path (through a temporary file: a reader never sees half). */
static void dump(void) {
    char tmp[512];
    snprintf(tmp, sizeof tmp, "%s.tmp", out_path);
    FILE *f = fopen(tmp, "w");
    if (!f) return;
    for (uint32_t i = 0; i < PCS; i++)
        if (pcs[i]) fprintf(f, "%#x %llu\n", i * 2, (unsigned long long)pcs[i]);
    fclose(f);
    rename(tmp, out_path);
}

static void *dumper(void *arg) {
    for (;;) { sleep(1); dump(); }
    return NULL;
}

static void at_exit(qemu_plugin_id_t id, void *p) { dump(); }

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc, char **argv) {
    for (int i = 0; i < argc; i++) {
        if (!strncmp(argv[i], "out=", 4)) out_path = argv[i] + 4;
        else if (!strncmp(argv[i], "on=", 3)) on_name = argv[i] + 3;
        else if (!strncmp(argv[i], "off=", 4)) off_name = argv[i] + 4;
        else if (!strncmp(argv[i], "keep=", 5)) keep_name = argv[i] + 5;
        else if (!strncmp(argv[i], "isr=", 4)) isr_name = argv[i] + 4;
    }
    if (!out_path || !on_name != !off_name) return -1;
    pthread_t t;
    pthread_create(&t, NULL, dumper, NULL);
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
