/* symprof: executed instructions per ELF symbol (the function the instruction belongs to after
 * inlining), summed over the whole run and printed at exit, largest first.
 *
 * qemu-system-arm ... -plugin ./libsymprof.so -d plugin -D /tmp/prof.log
 * With -plugin ./libsymprof.so,out=FILE the table is rewritten to FILE every second (for a QEMU
 * that is killed rather than exiting), and the per-address counts to FILE.pcs.
 * With on=SYM,off=SYM the per-address counts cover only what runs between calls of the two
 * functions (the firmware's measured regions: strata_counted_on/off).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <unistd.h>
#include "qemu-plugin-v1.h"

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

#define MAXS 8192
static struct { const char *name; uint64_t insns; } syms[MAXS];
static int nsyms;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

/* Counter of a symbol (by name; a linear search at translation time only). */
static uint64_t *counter(const char *name) {
    for (int i = 0; i < nsyms; i++)
        if (syms[i].name == name || !strcmp(syms[i].name, name)) return &syms[i].insns;
    if (nsyms == MAXS) return &syms[MAXS - 1].insns;
    pthread_mutex_lock(&lock);
    syms[nsyms].name = strdup(name);
    uint64_t *c = &syms[nsyms].insns;
    nsyms++;
    pthread_mutex_unlock(&lock);
    return c;
}

/* Per-halfword counts over the first 1 MB of the address space (flash), for addr2line. */
#define PCS (1u << 19)
static uint64_t pcs[PCS];

/* Counted mode (on=SYM,off=SYM): only instructions executed between a call of `on` and the
 * next call of `off` are counted per address (a callback per instruction: slower). */
static const char *on_name, *off_name;
static uint64_t on_addr = ~0ull, off_addr = ~0ull;
static int recording;

static void set_on(unsigned int vcpu, void *u) { recording = 1; }
static void set_off(unsigned int vcpu, void *u) { recording = 0; }
static void count_if_on(unsigned int vcpu, void *u) {
    if (recording) ++*(uint64_t *)u;
}

static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t va = qemu_plugin_insn_vaddr(insn);
        const char *s = qemu_plugin_insn_symbol(insn);
        if (on_name && i == 0 && s) {
            if (on_addr == ~0ull && !strcmp(s, on_name)) on_addr = va;
            if (off_addr == ~0ull && !strcmp(s, off_name)) off_addr = va;
        }
        if (va == on_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, set_on, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == off_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, set_off, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va / 2 < PCS) {
            if (on_name)
                qemu_plugin_register_vcpu_insn_exec_cb(insn, count_if_on, QEMU_PLUGIN_CB_NO_REGS, &pcs[va / 2]);
            else
                qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, &pcs[va / 2], 1);
        }
        const char *sym = qemu_plugin_insn_symbol(insn);
        qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, counter(sym ? sym : "?"), 1);
    }
}

static int by_count(const void *a, const void *b) {
    uint64_t x = *(const uint64_t *)((const char *)a + sizeof(char *));
    uint64_t y = *(const uint64_t *)((const char *)b + sizeof(char *));
    return x < y ? 1 : x > y ? -1 : 0;
}

static const char *out_path;

/* Writes the sorted table to out_path (a copy: the counters keep running). */
static void dump(void) {
    static struct { const char *name; uint64_t insns; } snap[MAXS];
    pthread_mutex_lock(&lock);
    int n = nsyms;
    memcpy(snap, syms, n * sizeof snap[0]);
    pthread_mutex_unlock(&lock);
    uint64_t total = 0;
    for (int i = 0; i < n; i++) total += snap[i].insns;
    qsort(snap, n, sizeof snap[0], by_count);
    char tmp[512];
    snprintf(tmp, sizeof tmp, "%s.tmp", out_path);
    FILE *f = fopen(tmp, "w");
    if (!f) return;
    fprintf(f, "total %llu\n", (unsigned long long)total);
    for (int i = 0; i < n && snap[i].insns; i++)
        fprintf(f, "%14llu %6.2f%% %s\n", (unsigned long long)snap[i].insns, 100.0 * snap[i].insns / (total ? total : 1), snap[i].name);
    fclose(f);
    rename(tmp, out_path);
    snprintf(tmp, sizeof tmp, "%s.pcs", out_path);
    f = fopen(tmp, "w");
    if (!f) return;
    for (uint32_t i = 0; i < PCS; i++)
        if (pcs[i]) fprintf(f, "%#x %llu\n", i * 2, (unsigned long long)pcs[i]);
    fclose(f);
}

static void *dumper(void *arg) {
    for (;;) { sleep(1); dump(); }
    return NULL;
}

static void at_exit(qemu_plugin_id_t id, void *p) {
    if (out_path) { dump(); return; }
    uint64_t total = 0;
    for (int i = 0; i < nsyms; i++) total += syms[i].insns;
    qsort(syms, nsyms, sizeof syms[0], by_count);
    char line[512];
    snprintf(line, sizeof line, "symprof: total %llu\n", (unsigned long long)total);
    qemu_plugin_outs(line);
    for (int i = 0; i < nsyms && syms[i].insns; i++) {
        snprintf(line, sizeof line, "symprof: %14llu %6.2f%% %s\n", (unsigned long long)syms[i].insns,
                 100.0 * syms[i].insns / (total ? total : 1), syms[i].name);
        qemu_plugin_outs(line);
    }
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc, char **argv) {
    for (int i = 0; i < argc; i++)
        if (!strncmp(argv[i], "out=", 4)) out_path = argv[i] + 4;
        else if (!strncmp(argv[i], "on=", 3)) on_name = argv[i] + 3;
        else if (!strncmp(argv[i], "off=", 4)) off_name = argv[i] + 4;
    if (!on_name != !off_name) return -1;
    if (out_path) { pthread_t t; pthread_create(&t, NULL, dumper, NULL); }
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
