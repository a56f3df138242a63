#!/usr/bin/env python3
"""Synthesis checks and resource estimates for every entity in ``rtl/files.f``.

``--check``  (``make test``): ``ghdl --synth`` of every entity with its default generics (and
             of the builds in ``VARIANTS``, e.g. the CANopen-only top with OMNI_ENABLE = false),
             producing the same Verilog netlist as ``make synth`` (then discarded). GHDL
             rejects latches (no ``--latches``), ``wait for`` and other non-synthesizable code,
             and evaluates the elaboration-time assertions.
default      (``make synth``): GHDL synthesis to Verilog, a fix-up of GHDL 2.0's one-hot
             ``case`` blocks (they have no ``default`` arm, which makes yosys infer false
             latches: see shared/spec/toolchain.md §4), then yosys ``synth_intel -family
             cycloneiv`` (Cyclone IV E has the same 4-input-LUT logic element as the reference
             Cyclone III EP3C80). Writes ``build/synth/report.json`` as
             ``{"<entity>": {"luts": N, "ffs": N}}`` and prints a table. Any latch is an error.

These are estimates (yosys/ABC, not Quartus): packing and carry chains differ.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RTL = ROOT / "rtl"
OUT = ROOT / "build" / "synth"
LIB = "canopen_master"
ENV = dict(os.environ, GHDL_BACKEND=os.environ.get("GHDL_BACKEND", "llvm"))
#: VHDL standard of the RTL (Quartus versions for Cyclone III read VHDL-2008 only in part)
STD = "93c"
#: standard of the simulations (tb/tblib/runner.py): the RTL must analyse under it too
SIM_STD = "08"


def sources() -> list[Path]:
    files = []
    for line in (RTL / "files.f").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            files.append(RTL / line)
    return files


def entities(files: list[Path]) -> list[str]:
    names = []
    for f in files:
        for m in re.finditer(r"^\s*entity\s+(\w+)\s+is", f.read_text(), re.I | re.M):
            names.append(m.group(1).lower())
    return names


def run(cmd: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, env=ENV, text=True, capture_output=True, **kw)


def analyse(work: Path, std: str = STD) -> None:
    work.mkdir(parents=True, exist_ok=True)
    res = run(["ghdl", "-a", f"--std={std}", f"--work={LIB}", *map(str, sources())], work)
    if res.returncode:
        sys.exit(f"ghdl -a --std={std} failed:\n{res.stdout}{res.stderr}")


def add_case_defaults(verilog: str) -> str:
    """Give every ``case`` without a ``default`` arm one that assigns 'x to its target."""
    out: list[str] = []
    block: list[str] | None = None
    for line in verilog.splitlines():
        if re.match(r"\s*case\s*\(", line):
            block = [line]
            continue
        if block is not None:
            block.append(line)
            if re.match(r"\s*endcase\b", line):
                body = "\n".join(block)
                if "default" not in body:
                    m = re.search(r":\s*(\w+)\s*<?=", body)
                    if m:
                        indent = re.match(r"\s*", line).group(0) + "  "
                        block.insert(len(block) - 1, f"{indent}default: {m.group(1)} <= 'bx;")
                out.extend(block)
                block = None
            continue
        out.append(line)
    return "\n".join(out) + "\n"


#: builds reported besides each entity with its defaults: report name -> (entity, generics)
VARIANTS = {"canopen_master_top_canopen_only": ("canopen_master_top", ["-gOMNI_ENABLE=false"])}


def targets(names: list[str]) -> list[tuple[str, str, list[str]]]:
    """(report name, entity, generic options) of every build to check or estimate."""
    return [(n, n, []) for n in names] + [(k, e, g) for k, (e, g) in VARIANTS.items()
                                          if e in names]


def check(names: list[str]) -> int:
    analyse(OUT / "check08", SIM_STD)
    print(f"ghdl -a --std={SIM_STD} of rtl/files.f       ok")
    work = OUT / "check"
    analyse(work)
    failed = 0
    for name, entity, gens in targets(names):
        res = run(["ghdl", "--synth", f"--std={STD}", f"--work={LIB}", *gens, "--out=verilog",
                   entity], work)
        status = "ok" if res.returncode == 0 else "FAILED"
        print(f"ghdl --synth {name:32s} {status}")
        if res.returncode:
            failed += 1
            print(res.stdout + res.stderr)
    return failed


def estimate(names: list[str]) -> dict[str, dict[str, int]]:
    if shutil.which("yosys") is None:
        sys.exit("yosys not found: run make setup")
    work = OUT / "work"
    analyse(work)
    report: dict[str, dict[str, int]] = {}
    for name, entity, gens in targets(names):
        res = run(["ghdl", "--synth", f"--std={STD}", f"--work={LIB}", *gens, "--out=verilog",
                   entity], work)
        if res.returncode:
            sys.exit(f"ghdl --synth {name} failed:\n{res.stderr}")
        vfile = work / f"{name}.v"
        vfile.write_text(add_case_defaults(res.stdout))
        script = (
            f"read_verilog {vfile}; synth_intel -family cycloneiv -top {entity}; "
            f"tee -o {work / (name + '.stat')} stat"
        )
        yres = run(["yosys", "-q", "-l", str(work / f"{name}.yosys.log"), "-p", script], work)
        if yres.returncode:
            sys.exit(f"yosys failed for {name}:\n{yres.stdout}{yres.stderr}")
        stat = (work / f"{name}.stat").read_text()
        cells = {m.group(1): int(m.group(2))
                 for m in re.finditer(r"^\s+(\S+)\s+(\d+)\s*$", stat, re.M)}
        latches = sum(v for k, v in cells.items() if "latch" in k.lower())
        if latches:
            sys.exit(f"{name}: {latches} latch cells inferred: {cells}")
        luts = sum(v for k, v in cells.items() if "lcell_comb" in k)
        ffs = sum(v for k, v in cells.items() if k.endswith("dffeas") or k.startswith("$_DFF"))
        report[name] = {"luts": luts, "ffs": ffs}
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="synthesizability gate only")
    args = ap.parse_args()
    names = entities(sources())
    if args.check:
        sys.exit(1 if check(names) else 0)
    report = estimate(names)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "report.json").write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
    print(f"\n{'entity':32s} {'LUTs':>8s} {'FFs':>8s}   (yosys synth_intel cycloneiv)")
    for name, r in report.items():
        print(f"{name:32s} {r['luts']:8d} {r['ffs']:8d}")
    print(f"\nwritten: {OUT / 'report.json'}")


if __name__ == "__main__":
    main()
