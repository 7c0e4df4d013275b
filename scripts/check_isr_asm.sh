#!/usr/bin/env bash
# The step interrupt must do integer adds and compares only: no division instruction, no
# software division or floating-point helper (the Cortex-M3 has no FPU), on the whole path
# `Executor::on_timer` reaches. Builds tools/isr-probe for thumbv7m-none-eabi (release),
# disassembles it and walks the call graph from `strata_step_isr`. Exits 1 on a finding.
# A self-test first checks that the walk flags two probe functions that do divide / use
# floats. Also reports panic paths and where 64-bit arithmetic (adc/sbc, long multiplies)
# is. Needs `rustup component add llvm-tools` (or llvm-objdump on PATH) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."

OBJDUMP="$(rustc --print sysroot)/lib/rustlib/x86_64-unknown-linux-gnu/bin/llvm-objdump"
[ -x "$OBJDUMP" ] || OBJDUMP="$(command -v llvm-objdump || true)"
if [ -z "$OBJDUMP" ]; then
  rustup component add llvm-tools
  OBJDUMP="$(rustc --print sysroot)/lib/rustlib/x86_64-unknown-linux-gnu/bin/llvm-objdump"
fi
rustup target list --installed | grep -qx thumbv7m-none-eabi || rustup target add thumbv7m-none-eabi

TARGET_DIR="${CARGO_TARGET_DIR:-$PWD/target}/isr_probe"
cargo build --quiet --manifest-path tools/isr-probe/Cargo.toml --release \
  --target thumbv7m-none-eabi --target-dir "$TARGET_DIR"
LIB="$TARGET_DIR/thumbv7m-none-eabi/release/libisr_probe.a"
DIS="$TARGET_DIR/isr_probe.dis"
"$OBJDUMP" -d -r --no-show-raw-insn "$LIB" > "$DIS"

python3 - "$DIS" <<'PY'
import re, sys

text = open(sys.argv[1]).read()
funcs, cur = {}, None
for line in text.splitlines():
    m = re.match(r'^[0-9a-f]+ <(.+)>:$', line)
    if m:
        cur = m.group(1)
        funcs.setdefault(cur, [])
    elif cur is not None and line.strip():
        funcs[cur].append(line)

def callees(name):
    out = set()
    for l in funcs.get(name, []):
        m = re.search(r'R_ARM_THM_(?:CALL|JUMP24|JUMP19)\s+(\S+)', l)
        if m:
            out.add(m.group(1))
    return out

DIV_INSN = re.compile(r'\s(udiv|sdiv)\b')
FP_INSN = re.compile(r'\sv[a-z0-9.]+\s')   # any VFP instruction
BAD_CALL = re.compile(r'^(__aeabi_(u?i?l?div|u?idivmod|uldivmod|ldivmod|[fd]\w+|[ui]?[l]?2[fd]|f2\w+|d2\w+)'
                      r'|__u?(div|mod)[sdt]i3|__u?divmod\w+|__(add|sub|mul|div|neg)[sdt]f3'
                      r'|__(fix|float)\w+|__(eq|ne|lt|le|gt|ge|un|cmp)[sd]f2|__extend\w+|__trunc\w+)$')

def walk(root):
    seen, stack, findings, panics = set(), [root], [], set()
    while stack:
        f = stack.pop()
        if f in seen:
            continue
        seen.add(f)
        if BAD_CALL.match(f):
            findings.append(f'call to {f}')
            continue
        if 'panic' in f:
            panics.add(f)
            continue
        for l in funcs.get(f, []):
            if DIV_INSN.search(l):
                findings.append(f'{f}: {l.strip()}')
            if FP_INSN.search(l):
                findings.append(f'{f}: {l.strip()}')
        stack.extend(callees(f))
    return seen, findings, panics

ok = True
for probe in ('strata_probe_divides', 'strata_probe_floats'):
    _, found, _ = walk(probe)
    if not found:
        print(f'self-test FAILED: nothing flagged in {probe}')
        ok = False
if 'strata_step_isr' not in funcs:
    print('strata_step_isr not found in the disassembly')
    sys.exit(1)
seen, found, panics = walk('strata_step_isr')
insns = sum(len(funcs.get(f, [])) for f in seen)
print(f'step ISR: {len(seen)} function(s), {insns} instructions reachable from strata_step_isr')
for f in sorted(seen):
    print(f'  {f}')
if panics:
    print('note: reachable panic paths (bounds/overflow checks):', ', '.join(sorted(panics)))
else:
    print('OK: no panic path (bounds or overflow check) on the ISR path')
# 64-bit arithmetic shows as add/subtract with carry or long multiplies: say where it is
# (the executor keeps it out of the per-step path: only where a sequence ends).
WIDE = re.compile(r'\s(adcs?|sbcs?|umull|smull|umlal|smlal)(\.w)?\s')
for f in sorted(seen):
    n = sum(1 for l in funcs.get(f, []) if WIDE.search(l))
    if n:
        print(f'note: {n} 64-bit arithmetic instruction(s) (adc/sbc/long multiply) in {f}')
if found:
    print('FAIL: division or floating point on the ISR path:')
    for x in found:
        print('  ' + x)
    ok = False
else:
    print('OK: no division, no floating point on the ISR path')
sys.exit(0 if ok else 1)
PY
