#!/usr/bin/env python3
"""Synthesis checks and resource estimates for every entity in ``rtl/files.f``.

``--check``  (``make test``): ``ghdl -a --std=08`` of every RTL file (the simulations' standard),
             then ``ghdl -a`` and ``ghdl --synth`` with ``--std=93c`` (``STD``: the RTL is
             VHDL-93) of every entity with its default generics and of
             the builds in ``VARIANTS`` (the CANopen-only top, the channel-count variants),
             producing the same Verilog netlist as ``make synth`` (then discarded). GHDL rejects
             latches (no ``--latches``), ``wait for`` and other non-synthesizable code, and
             evaluates the elaboration-time assertions.
default      (``make synth``): GHDL synthesis to Verilog, a fix-up of GHDL 2.0's one-hot
             ``case`` blocks (they have no ``default`` arm, which makes yosys infer false
             latches), then yosys ``synth_intel -family cycloneive`` (Cyclone IV E: the same
             4-input-LUT logic element and M9K block RAM as the reference Cyclone III EP3C80;
             yosys' ``cycloneiv`` is Cyclone IV GX). One progress line per build as it finishes.
             Per build: LUTs, FFs, M9K blocks (and the RAM bits mapped into them), and the logic
             depth in LUT levels computed on the mapped netlist (``logic_depth``). The slopes
             of ``SLOPES`` (LUTs and FFs per extra PDO / SDO channel) come from two builds each.
             Writes ``build/synth/report.json`` and prints a table. Any latch is an error.

These are estimates (yosys/ABC, not Quartus): packing, carry chains and retiming differ. How each
figure is counted: docs/resources.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RTL = ROOT / "rtl"
OUT = ROOT / "build" / "synth"
LIB = "canopen_master"
ENV = dict(os.environ, GHDL_BACKEND=os.environ.get("GHDL_BACKEND", "llvm"))
#: VHDL standard of the RTL, of every ghdl --synth and of the FuseSoC generator (the Quartus
#: versions for Cyclone III read VHDL-2008 only in part)
STD = "93c"
#: standard of the simulations (tb/tblib/runner.py): the RTL must analyse under it too
SIM_STD = "08"
#: yosys synth_intel family: Cyclone IV E (the LE and M9K of Cyclone III)
FAMILY = "cycloneive"

#: mapped cell types: 4-input LUT, register, M9K block RAM
LUT_CELL = f"{FAMILY}_lcell_comb"
FF_CELL = "dffeas"
RAM_CELL = "altsyncram"
#: cells that start and end a timing path (their clock inputs are not path ends)
SEQ_CELLS = {FF_CELL, RAM_CELL}
CLOCK_PORTS = {"clk", "clock0", "clock1"}
#: LUT levels a cell adds to a path; an unlisted combinational cell type counts 1. ``$not``
#: (synth_intel turns a 1-input LUT into an inverter) counts 0: Quartus folds it into the LUT
#: it feeds. ``$mux`` cells left unmapped by synth_intel (created by opt_share after ABC) are
#: one LUT per bit.
LEVELS = {LUT_CELL: 1, "$not": 0, "$_NOT_": 0}

#: builds reported besides each entity with its defaults: report name -> (entity, generics)
VARIANTS: dict[str, tuple[str, dict[str, str]]] = {
    "canopen_master_top_canopen_only": ("canopen_master_top", {"OMNI_ENABLE": "false"}),
    "canopen_master_top_canopen_only_pdo12": (
        "canopen_master_top", {"OMNI_ENABLE": "false", "N_TPDO": "12", "N_RPDO": "12"}),
    "canopen_master_top_canopen_only_sdo4": (
        "canopen_master_top", {"OMNI_ENABLE": "false", "N_SDO": "4"}),
    "canopen_pdo_engine_pdo12": ("canopen_pdo_engine", {"N_TPDO": "12", "N_RPDO": "12"}),
    "canopen_sdo_channels_sdo4": ("canopen_sdo_channels", {"N_SDO": "4"}),
}
#: slope name -> (base build, build with more channels, extra channels of either kind)
SLOPES = {
    "pdo": ("canopen_master_top_canopen_only", "canopen_master_top_canopen_only_pdo12", 8),
    "sdo": ("canopen_master_top_canopen_only", "canopen_master_top_canopen_only_sdo4", 2),
}


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


def ghdl_synth(entity: str, generics: dict[str, str], work: Path) -> subprocess.CompletedProcess:
    gens = [f"-g{k}={v}" for k, v in generics.items()]
    return run(["ghdl", "--synth", f"--std={STD}", f"--work={LIB}", *gens, "--out=verilog",
                entity], work)


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


def targets(names: list[str]) -> list[tuple[str, str, dict[str, str]]]:
    """(report name, entity, generics) of every build to check or estimate."""
    return [(n, n, {}) for n in names] + [(k, e, g) for k, (e, g) in VARIANTS.items()
                                          if e in names]


def check(names: list[str]) -> int:
    analyse(OUT / "check08", SIM_STD)
    print(f"ghdl -a --std={SIM_STD} of rtl/files.f       ok")
    work = OUT / "check"
    analyse(work)
    failed = 0
    for name, entity, gens in targets(names):
        res = ghdl_synth(entity, gens, work)
        status = "ok" if res.returncode == 0 else "FAILED"
        print(f"ghdl --synth {name:40s} {status}")
        if res.returncode:
            failed += 1
            print(res.stdout + res.stderr)
    return failed


# ------------------------------------------------------------------ mapped-netlist analysis
def _width(cell: dict) -> int:
    w = cell.get("parameters", {}).get("WIDTH", "1")
    return int(w, 2) if isinstance(w, str) else int(w)


def _bit_names(module: dict) -> dict[int, str]:
    """A readable name per net bit: public names (no ``$``) before generated ones."""
    names: dict[int, str] = {}
    for hidden in (False, True):
        for net, info in module.get("netnames", {}).items():
            if bool(info.get("hide_name")) != hidden:
                continue
            bits = info["bits"]
            for i, b in enumerate(bits):
                if isinstance(b, int) and b not in names:
                    names[b] = net if len(bits) == 1 else f"{net}[{i}]"
    return names


def cell_counts(module: dict) -> dict[str, int]:
    """Cell type -> number of cells (bits for coarse ``$`` cells) of a mapped module."""
    counts: dict[str, int] = {}
    for cell in module["cells"].values():
        t = cell["type"]
        n = _width(cell) if t.startswith("$") and not t.startswith("$_") else 1
        counts[t] = counts.get(t, 0) + n
    return counts


def logic_depth(module: dict) -> dict[str, object]:
    """Longest combinational path of a flattened, mapped module, in LUT levels.

    Paths start at a register output (``dffeas`` q, M9K read data), at an input port or at a
    constant, and end at a register input (every ``dffeas``/M9K input except the clock: data,
    enable, asynchronous clear) or at an output port. A cell adds ``LEVELS`` (default 1) to a
    path: a LUT one level, an inverter none. Returns ``levels`` (register to register),
    ``levels_io`` (the longest path that starts or ends at a port, 0 if none) and the end
    points of the longest register-to-register path. A combinational loop is an error.
    """
    driver: dict[int, str] = {}
    inputs: dict[str, list[int]] = {}
    ends: list[tuple[int, str]] = []
    for name, cell in module["cells"].items():
        dirs = cell.get("port_directions", {})
        conns = cell["connections"]
        if cell["type"] in SEQ_CELLS:
            ends += [(b, "reg") for p, bits in conns.items()
                     if dirs.get(p) == "input" and p not in CLOCK_PORTS
                     for b in bits if isinstance(b, int)]
            continue
        if not dirs:
            raise ValueError(f"cell {name} ({cell['type']}): port directions unknown")
        inputs[name] = [b for p, bits in conns.items() if dirs[p] == "input"
                        for b in bits if isinstance(b, int)]
        for p, bits in conns.items():
            if dirs[p] == "output":
                for b in bits:
                    if isinstance(b, int):
                        driver[b] = name
    in_ports = set()
    for port in module.get("ports", {}).values():
        bits = [b for b in port["bits"] if isinstance(b, int)]
        if port["direction"] == "input":
            in_ports.update(bits)
        else:
            ends += [(b, "port") for b in bits]

    neg = -1 << 30  # "no such path"
    # per combinational cell: (levels from a register start, start bit), levels from a port
    level: dict[str, tuple[int, int, int]] = {}

    def bit_level(b: int) -> tuple[int, int, int]:
        if b in driver:
            return level[driver[b]]
        if b in in_ports:
            return (neg, b, 0)
        return (0, b, neg)  # register output or undriven/constant net

    for root in inputs:
        if root in level:
            continue
        stack = [(root, False)]
        onstack: set[str] = set()
        while stack:
            name, done = stack.pop()
            if done:
                onstack.discard(name)
                reg, start, io = neg, -1, neg
                for b in inputs[name]:
                    r, s, p = bit_level(b)
                    if r > reg:
                        reg, start = r, s
                    io = max(io, p)
                w = LEVELS.get(module["cells"][name]["type"], 1)
                level[name] = (reg + w, start, io + w)
                continue
            if name in level:
                continue
            if name in onstack:
                raise ValueError(f"combinational loop through cell {name}")
            onstack.add(name)
            stack.append((name, True))
            for b in inputs[name]:
                d = driver.get(b)
                if d is not None and d not in level:
                    if d in onstack:
                        raise ValueError(f"combinational loop through cell {d}")
                    stack.append((d, False))

    names = _bit_names(module)
    best, best_start, best_end, io_best = 0, None, None, 0
    for b, kind in ends:
        r, s, p = bit_level(b)
        if kind == "reg" and r > best:
            best, best_start, best_end = r, s, b
        io_best = max(io_best, p, r if kind == "port" else 0)
    return {
        "levels": best,
        "levels_io": io_best,
        "path_from": names.get(best_start, str(best_start)) if best_end is not None else None,
        "path_to": names.get(best_end, str(best_end)) if best_end is not None else None,
    }


def ram_blocks(log: str) -> list[dict[str, object]]:
    """The inferred memories of a yosys ``synth_intel`` log: name, bits and the number of M9K
    blocks ``memory_bram`` made of each (0: left to ``memory_map``, i.e. FFs and LUTs)."""
    mems: list[dict[str, object]] = []
    section = log.split("Executing MEMORY_BRAM pass", 1)
    if len(section) < 2:
        return mems
    body = section[1].split("Executing MEMORY_MAP pass", 1)[0]
    for m in re.finditer(r"^Processing ([^\n]+?):\n\s+Properties:[^\n]*?\bbits=(\d+)"
                         r"[^\n]*?\bdbits=(\d+)[^\n]*?\bwords=(\d+)(.*?)(?=^Processing |\Z)",
                         body, re.M | re.S):
        blocks = len(re.findall(r"Creating \S+ cell at grid position", m.group(5)))
        mems.append({"memory": m.group(1).strip(), "bits": int(m.group(2)),
                     "width": int(m.group(3)), "words": int(m.group(4)), "m9k": blocks})
    return mems


def analyse_netlist(netlist: dict, top: str, log: str) -> dict[str, object]:
    """Resource and depth figures of one mapped netlist (``write_json``) and its yosys log."""
    module = netlist["modules"][top]
    counts = cell_counts(module)
    latches = sum(v for k, v in counts.items() if "latch" in k.lower())
    if latches:
        raise ValueError(f"{latches} latch cells inferred: {counts}")
    ffs = counts.get(FF_CELL, 0) + sum(v for k, v in counts.items() if k.startswith("$_DFF"))
    other = {k: v for k, v in counts.items()
             if k not in (LUT_CELL, FF_CELL, RAM_CELL) and not k.startswith("$_DFF")}
    mems = ram_blocks(log)
    m9k = counts.get(RAM_CELL, 0)
    if m9k != sum(int(m["m9k"]) for m in mems):
        raise ValueError(f"{m9k} {RAM_CELL} cells, but the log maps {mems}")
    return {
        # every LUT-sized function: the mapped LUTs plus cells synth_intel left unmapped
        # (1-bit $mux, $not), each at most one logic element
        "luts": counts.get(LUT_CELL, 0) + sum(other.values()),
        "ffs": ffs,
        "m9k": m9k,
        "ram_bits": sum(int(m["bits"]) for m in mems if m["m9k"]),
        "memories_in_logic": [m["memory"] for m in mems if not m["m9k"]],
        "unmapped_cells": other,
        **logic_depth(module),
    }


def synth_one(name: str, entity: str, vfile: Path, work: Path) -> dict[str, object]:
    """yosys on one fixed-up GHDL netlist; returns the figures of ``analyse_netlist``."""
    log = work / f"{name}.yosys.log"
    net = work / f"{name}.json"
    script = (f"read_verilog {vfile}; synth_intel -family {FAMILY} -top {entity}; "
              f"tee -o {work / (name + '.stat')} stat; write_json {net}")
    t0 = time.monotonic()
    yres = run(["yosys", "-q", "-l", str(log), "-p", script], work)
    if yres.returncode:
        raise RuntimeError(f"yosys failed for {name}:\n{yres.stdout}{yres.stderr}")
    text = log.read_text()
    try:
        r = analyse_netlist(json.loads(net.read_text()), entity, text)
    except ValueError as e:
        raise RuntimeError(f"{name}: {e}") from e
    net.unlink()  # tens of MB for the top; the log and the .stat stay
    r["seconds"] = round(time.monotonic() - t0, 1)
    return r


def describe(gens: dict[str, str]) -> str:
    return " ".join(f"{k}={v}" for k, v in gens.items()) or "defaults"


def estimate(names: list[str], jobs: int, only: list[str] | None = None) -> dict[str, dict]:
    if shutil.which("yosys") is None:
        sys.exit("yosys not found: run make setup")
    work = OUT / "work"
    analyse(work)
    builds = [t for t in targets(names) if not only or t[0] in only]
    if not builds:
        sys.exit(f"no build named {only}; builds: {[t[0] for t in targets(names)]}")
    todo = []
    for name, entity, gens in builds:
        res = ghdl_synth(entity, gens, work)
        if res.returncode:
            sys.exit(f"ghdl --synth {name} failed:\n{res.stderr}")
        vfile = work / f"{name}.v"
        vfile.write_text(add_case_defaults(res.stdout))
        todo.append((vfile.stat().st_size, name, entity, gens, vfile))
    todo.sort(key=lambda t: -t[0])  # largest netlist first: the longest run starts first
    report: dict[str, dict] = {}
    print(f"yosys synth_intel -family {FAMILY}: {len(todo)} builds, {jobs} at a time", flush=True)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(synth_one, name, entity, vfile, work): (name, gens)
                   for _, name, entity, gens, vfile in todo}
        for fut in as_completed(futures):
            name, gens = futures[fut]
            try:
                r = fut.result()
            except RuntimeError as e:
                for f in futures:
                    f.cancel()
                sys.exit(str(e))
            r["generics"] = gens
            report[name] = r
            print(f"[{len(report):2d}/{len(todo)}] {name:40s} {describe(gens):32s} "
                  f"{r['luts']:6d} LUT {r['ffs']:6d} FF {r['m9k']:3d} M9K "
                  f"{r['levels']:3d} levels {r['seconds']:7.1f} s", flush=True)
    return dict(sorted(report.items()))


def slopes(report: dict[str, dict]) -> dict[str, dict]:
    out = {}
    for kind, (base, more, extra) in SLOPES.items():
        if base in report and more in report:
            b, m = report[base], report[more]
            out[kind] = {"base": base, "more": more, "extra_channels": extra,
                         "luts_per_channel": round((m["luts"] - b["luts"]) / extra, 1),
                         "ffs_per_channel": round((m["ffs"] - b["ffs"]) / extra, 1),
                         "m9k_per_channel": round((m["m9k"] - b["m9k"]) / extra, 2)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="synthesizability gate only")
    ap.add_argument("-j", "--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="yosys runs at a time (default: 2, or 1 on a 1-core machine)")
    ap.add_argument("--only", nargs="+", metavar="NAME",
                    help="estimate only these builds (entity or variant names); report.json "
                         "then holds only them")
    args = ap.parse_args()
    names = entities(sources())
    if args.check:
        sys.exit(1 if check(names) else 0)
    t0 = time.monotonic()
    report = estimate(names, max(1, args.jobs), args.only)
    total = round(time.monotonic() - t0, 1)
    # CPU time of all finished child processes (ghdl, yosys and its ABC runs): on a shared
    # machine a steadier figure than the wall time
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = round(kids.ru_utime + kids.ru_stime, 1)
    result = {
        "family": FAMILY,
        "builds": report,
        "slopes": slopes(report),
        "max_lut_levels": max(r["levels"] for r in report.values()),
        "wall_seconds": total,
        "cpu_seconds": cpu,
        "jobs": args.jobs,
    }
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "report.json").write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"\n{'build':40s} {'LUTs':>7s} {'FFs':>7s} {'M9K':>4s} {'RAM bits':>8s} "
          f"{'levels':>6s} {'io':>4s}   (yosys synth_intel {FAMILY})")
    for name, r in report.items():
        print(f"{name:40s} {r['luts']:7d} {r['ffs']:7d} {r['m9k']:4d} {r['ram_bits']:8d} "
              f"{r['levels']:6d} {r['levels_io']:4d}")
    for kind, s in result["slopes"].items():
        print(f"per extra {kind.upper()} channel ({s['base']} -> {s['more']}, "
              f"+{s['extra_channels']}): {s['luts_per_channel']} LUTs, "
              f"{s['ffs_per_channel']} FFs, {s['m9k_per_channel']} M9K")
    print(f"max LUT levels: {result['max_lut_levels']}; {total} s wall, {cpu} s CPU, "
          f"{args.jobs} job(s)")
    print(f"written: {OUT / 'report.json'}")


if __name__ == "__main__":
    main()
