"""Checks of the integration kit (no Quartus, no Nios II tools on these machines).

* ``canopen_master.core`` (FuseSoC CAPI=2): the rtl fileset is ``rtl/files.f`` in order, the
  targets name the right tools, device and files; ``fusesoc core list`` / ``core-info`` accept
  it, the ``sim`` target runs the VHDL smoke testbench through FuseSoC and edalize on GHDL
  (a doctored testbench makes that run fail), the ``synth`` target's flow (generator, edalize,
  yosys) runs on a tiny stand-in top, and ``run --setup`` of the ``quartus`` target writes a
  project script that makes the same assignments as ``scripts/quartus_project.tcl``.
* ``ip/canopen_master.sdc``: every register pattern is instance-independent and names a real
  register of the RTL (entity chain, signal, width); every pin synchroniser of the RTL is
  covered.
* ``ip/canopen_master_sw.tcl`` (Nios II SBT driver): run in ``tclsh`` with stub SBT commands:
  hw_class_name and version match ``ip/canopen_master_hw.tcl``, every listed file exists, every
  C/H file of ``sw/`` is listed, every ``#include "..."`` resolves through the include
  directories it declares.
* ``scripts/quartus_project.tcl``: run in ``tclsh`` with stub Quartus commands on the real
  repository: device, top, VHDL-93, the VHDL files of ``rtl/files.f`` in order (paths
  resolved from the project directory), the SDC, one placeholder location per MCP2510/clock/reset
  pin (valid, distinct F484 ball names) with an I/O standard.
* ``ip/reference_system/nios2_canopen_qsys.tcl``: run in ``tclsh`` with stub qsys-script
  commands: the component and every interface it uses exist in the ``_hw.tcl`` with the right
  kind, clock/reset/s0/irq are connected, mcp2510 exported, no address overlap, distinct IRQs.
* the Nios II example of ``docs/integration.md`` compiles against ``sw/`` (stub HAL headers).

Each checker returns its findings; the ``*_can_fail`` tests feed doctored copies.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from tb.tblib.runner import ROOT, RTL_DIR, rtl_sources
from tb.test_ip_package import HW_TCL, TOP_VHD, entity_interface, parse_component

CORE = ROOT / "canopen_master.core"
VLNV = "canopen_master:ip:canopen_master:1.0"
SDC = ROOT / "ip" / "canopen_master.sdc"
SW_TCL = ROOT / "ip" / "canopen_master_sw.tcl"
QUARTUS_TCL = ROOT / "scripts" / "quartus_project.tcl"
PINS_TCL = ROOT / "constraints" / "ep3c80_reference_pins.tcl"
QSYS_TCL = ROOT / "ip" / "reference_system" / "nios2_canopen_qsys.tcl"
SW_DIR = ROOT / "sw"
DEVICE, FAMILY = "EP3C80F484C8", "Cyclone III"
VENV_BIN = Path(sys.executable).parent
TCLSH = shutil.which("tclsh")  # Debian package tcl, installed by make setup


def _sub_once(text: str, pattern: str, repl: str) -> str:
    out, n = re.subn(pattern, repl, text, count=1, flags=re.MULTILINE)
    assert n == 1, f"no match for {pattern!r}"
    return out


def _run_tcl(tmp_path: Path, harness: str, script: Path, *args: str,
             cwd: Path | None = None) -> list[list[str]]:
    """Source ``script`` after ``harness`` (stub commands that record their calls); returns
    the recorded calls as word lists. A Tcl error fails with its message."""
    assert TCLSH, "tclsh not found: run make setup (Debian package tcl)"
    h = tmp_path / "harness.tcl"
    h.write_text(harness + "\nset argv [lrange $argv 1 end]\nset argc [llength $argv]\n"
                 "source [lindex $::script_argv 0]\n"
                 "foreach c $::calls { puts \"CALL\\x1f[join $c \\x1f]\" }\n")
    out = subprocess.run([TCLSH, str(h), str(script), *args], capture_output=True, text=True,
                         timeout=60, check=False, cwd=cwd or tmp_path,
                         env=dict(os.environ, TCL_SCRIPT=str(script)))
    if out.returncode:
        raise RuntimeError(f"tclsh {script.name}: {out.stderr.strip()}")
    return [line.split("\x1f")[1:] for line in out.stdout.splitlines()
            if line.startswith("CALL\x1f")]


def _stubs(*names: str) -> str:
    """Tcl stubs: each command appends its name and arguments to ::calls."""
    lines = ["set ::calls {}", "set ::script_argv [list [lindex $argv 0]]",
             "proc _rec {args} { lappend ::calls $args }"]
    lines += [f"proc {n} {{args}} {{ _rec {n} {{*}}$args }}" for n in names]
    return "\n".join(lines)


# ===================================================================== FuseSoC core
def core_problems(core: dict, order: list[Path], root: Path = ROOT) -> list[str]:
    """The core's rtl fileset against rtl/files.f, and the targets' tools and settings."""
    problems = []
    rtl = core.get("filesets", {}).get("rtl", {})
    listed = [f if isinstance(f, str) else next(iter(f)) for f in rtl.get("files", [])]
    expected = [p.relative_to(root).as_posix() for p in order]
    if listed != expected:
        problems.append(f"rtl fileset lists {listed}, rtl/files.f has {expected}")
    if rtl.get("file_type") != "vhdlSource-93":
        problems.append(f"rtl file_type {rtl.get('file_type')}, expected vhdlSource-93")
    if rtl.get("logical_name") != "canopen_master":
        problems.append(f"rtl logical_name {rtl.get('logical_name')}, expected canopen_master")
    for name, fs in core.get("filesets", {}).items():
        for f in fs.get("files", []):
            path = f if isinstance(f, str) else next(iter(f))
            if not (root / path).is_file():
                problems.append(f"fileset {name}: {path} does not exist")
    targets = core.get("targets", {})
    sim = targets.get("sim", {})
    if sim.get("flow_options", {}).get("tool") != "ghdl" or "rtl" not in sim.get("filesets", []):
        problems.append("target sim: expected the rtl fileset and flow tool ghdl")
    synth = targets.get("synth", {})
    opts = synth.get("flow_options", {})
    if (opts.get("tool"), opts.get("arch"), opts.get("yosys_synth_options")) != (
            "yosys", "intel", ["-family cycloneive"]):
        problems.append(f"target synth: expected yosys synth_intel -family cycloneive, got {opts}")
    quartus = targets.get("quartus", {})
    q = quartus.get("tools", {}).get("quartus", {})
    if (q.get("family"), q.get("device")) != (FAMILY, DEVICE):
        problems.append(f"target quartus: family/device {q.get('family')}/{q.get('device')}, "
                        f"expected {FAMILY}/{DEVICE}")
    constraint_files = [next(iter(f)) if isinstance(f, dict) else f
                        for fs in quartus.get("filesets", [])
                        for f in core.get("filesets", {}).get(fs, {}).get("files", [])]
    for need in ("constraints/ep3c80_reference.sdc", "constraints/ep3c80_reference_pins.tcl"):
        if need not in constraint_files:
            problems.append(f"target quartus: {need} missing")
    for t in ("default", "synth", "quartus"):
        if targets.get(t, {}).get("toplevel") != "canopen_master_top":
            problems.append(f"target {t}: toplevel {targets.get(t, {}).get('toplevel')}")
    return problems


def _load_core(text: str) -> dict:
    assert text.startswith("CAPI=2:"), "not a CAPI=2 core file"
    return yaml.safe_load(text)


def test_core_matches_files_f():
    problems = core_problems(_load_core(CORE.read_text()), rtl_sources(RTL_DIR / "files.f"))
    assert not problems, "canopen_master.core:\n" + "\n".join(problems)


def test_core_checker_can_fail():
    text, order = CORE.read_text(), rtl_sources(RTL_DIR / "files.f")
    bad = _sub_once(text, r"^      - rtl/canopen_pkg\.vhd\n", "")
    bad = _sub_once(bad, r"device: EP3C80F484C8", "device: EP3C40F484C8")
    problems = core_problems(_load_core(bad), order)
    assert any(p.startswith("rtl fileset lists") for p in problems), problems
    assert any(p.startswith("target quartus: family/device") for p in problems), problems
    # files.f gains a file the core does not list
    problems = core_problems(_load_core(text), [*order, RTL_DIR / "new_block.vhd"])
    assert any(p.startswith("rtl fileset lists") for p in problems), problems


def _fusesoc(*args: str, cores_root: Path = ROOT, cwd: Path) -> subprocess.CompletedProcess:
    exe = VENV_BIN / "fusesoc"
    assert exe.exists(), "fusesoc is not installed in the venv (requirements.txt pins it)"
    env = dict(os.environ, PATH=f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}",
               GHDL_BACKEND="llvm")
    return subprocess.run([str(exe), "--cores-root", str(cores_root), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300, check=False)


def test_fusesoc_core_list_and_info(tmp_path):
    res = _fusesoc("core", "list", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert re.search(rf"^{re.escape(VLNV)}\s*:\s*local", res.stdout, re.M), res.stdout
    res = _fusesoc("core-info", VLNV, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    targets = re.findall(r"^(\w+)\s*:", res.stdout.split("Targets:", 1)[-1], re.M)
    assert {"default", "sim", "synth", "quartus"} <= set(targets), res.stdout


def _run_sim_target(cores_root: Path, build: Path) -> subprocess.CompletedProcess:
    return _fusesoc("run", "--build-root", str(build), "--target", "sim", VLNV,
                    cores_root=cores_root, cwd=build.parent)


def test_fusesoc_sim_target_runs(tmp_path):
    """The GHDL target through FuseSoC/edalize: the smoke testbench passes."""
    res = _run_sim_target(ROOT, tmp_path / "build")
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    assert "canopen_master_smoke_tb: PASS (init failure reported at 477.65 us)" in out, out[-3000:]


def test_fusesoc_sim_target_can_fail(tmp_path):
    """A copy of the repository whose testbench expects another ID: the run fails."""
    copy = tmp_path / "repo"
    for d in ("rtl", "constraints", "scripts", "tb/vhdl"):
        shutil.copytree(ROOT / d, copy / d)
    shutil.copy(CORE, copy / CORE.name)
    tb = copy / "tb" / "vhdl" / "canopen_master_smoke_tb.vhd"
    tb.write_text(_sub_once(tb.read_text(), r"assert data = ID_RESET_C",
                            "assert data = CTRL_RESET_C"))
    res = _run_sim_target(copy, tmp_path / "build")
    out = res.stdout + res.stderr
    assert res.returncode != 0, out[-3000:]
    assert "ID reads 434F3031" in out, out[-3000:]


#: a tiny stand-in for canopen_master_top: the synth target's flow (generator, edalize,
#: yosys) in seconds instead of the real top's minutes
TINY_TOP = """library ieee;
    use ieee.std_logic_1164.all;

entity canopen_master_top is
    port (clk_i : in std_logic; sel_i : in std_logic_vector(1 downto 0);
          q_o : out std_logic_vector(3 downto 0));
end entity canopen_master_top;

architecture rtl of canopen_master_top is
begin
    reg_proc : process (clk_i) is
    begin
        if rising_edge(clk_i) then
            case sel_i is
                when "00" => q_o <= "0001";
                when "01" => q_o <= "0010";
                when "10" => q_o <= "0100";
                when others => q_o <= "1000";
            end case;
        end if;
    end process reg_proc;
end architecture rtl;
"""


def _tiny_repo(root: Path, vhdl: str) -> Path:
    (root / "rtl").mkdir(parents=True)
    shutil.copytree(ROOT / "scripts", root / "scripts")
    shutil.copy(CORE, root / CORE.name)
    (root / "rtl" / "tiny.vhd").write_text(vhdl)
    (root / "rtl" / "files.f").write_text("tiny.vhd\n")
    return root


def test_fusesoc_synth_target_flow(tmp_path):
    """The synth target of canopen_master.core on a tiny stand-in top: the generator writes a
    Verilog netlist and a core, edalize runs yosys synth_intel, a JSON netlist comes out."""
    repo = _tiny_repo(tmp_path / "repo", TINY_TOP)
    build = tmp_path / "build"
    res = _fusesoc("run", "--build-root", str(build), "--target", "synth", VLNV,
                   cores_root=repo, cwd=tmp_path)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    work = build / "canopen_master_ip_canopen_master_1.0" / "synth"
    assert (work / "canopen_master_ip_canopen_master_1.0.json").stat().st_size > 0
    log = (work / "yosys.log").read_text()
    assert "Executing SYNTH_INTEL pass" in log and "/intel/cycloneive/cells_sim.v" in log
    assert "canopen_master_top.v" in log  # the generator's netlist
    cells = dict(re.findall(r"^\s+(cycloneive_lcell_comb|dffeas)\s+(\d+)$", log, re.M))
    assert int(cells["dffeas"]) >= 3 and int(cells["cycloneive_lcell_comb"]) >= 1, cells


def test_fusesoc_synth_target_can_fail(tmp_path):
    """VHDL that GHDL rejects stops the generator, and with it the run."""
    repo = _tiny_repo(tmp_path / "repo", TINY_TOP.replace("q_o <= \"1000\";", "q_o <= 1000;"))
    res = _fusesoc("run", "--build-root", str(tmp_path / "build"), "--target", "synth", VLNV,
                   cores_root=repo, cwd=tmp_path)
    assert res.returncode != 0
    assert "ghdl -a failed" in res.stdout + res.stderr, (res.stdout + res.stderr)[-3000:]


# ============================================================================ SDC
@dataclass
class RtlUnit:
    file: Path
    text: str
    instances: dict[str, str] = field(default_factory=dict)  # instance label -> entity
    signals: dict[str, int | None] = field(default_factory=dict)  # name -> width (None: bit)


_SIG_RE = re.compile(r"^\s*signal\s+(\w+(?:\s*,\s*\w+)*)\s*:\s*(\w+)(?:\s*\(\s*(\d+)\s+downto\s+"
                     r"(\d+)\s*\))?", re.I | re.M)


def rtl_units(files: dict[str, str]) -> dict[str, RtlUnit]:
    """Entity name -> its file text, instances and signals (regular expressions)."""
    units = {}
    for name, text in files.items():
        code = re.sub(r"--[^\n]*", "", text)
        for m in re.finditer(r"^\s*entity\s+(\w+)\s+is", code, re.I | re.M):
            u = RtlUnit(Path(name), code)
            u.instances = {i.group(1).lower(): i.group(2).lower() for i in re.finditer(
                r"^\s*(\w+)\s*:\s*entity\s+work\.(\w+)", code, re.I | re.M)}
            for s in _SIG_RE.finditer(code):
                width = (int(s.group(3)) - int(s.group(4)) + 1) if s.group(3) else None
                for n in s.group(1).split(","):
                    u.signals[n.strip().lower()] = width
            units[m.group(1).lower()] = u
    return units


def _rtl_texts(order: list[Path]) -> dict[str, str]:
    return {p.name: p.read_text() for p in order}


def _sdc_targets(sdc: str) -> list[str]:
    return re.findall(r"set_false_path\s+-to\s+\[get_(?:registers|pins)[^{]*\{([^}]*)\}\]", sdc)


def sdc_problems(sdc: str, files: dict[str, str]) -> list[str]:
    """Every false-path target: '*canopen_master_top:*|' + ('<entity>:*|')* + register[idx]
    (+ '|clrn' for a pin), each entity instantiated by the previous one, the register a signal
    of the last entity with a valid index. Every 2-flop synchroniser of a top-level input port
    (a signal shifted as 'x <= x(0) & <port>_i') has its first flop cut."""
    units = rtl_units(files)
    problems = []
    targets = _sdc_targets(sdc)
    if not targets:
        return ["no set_false_path -to [get_registers|get_pins {...}] in the SDC"]
    covered = set()
    for t in targets:
        parts = t.split("|")
        if parts[0] != "*canopen_master_top:*":
            problems.append(f"{t}: must start with '*canopen_master_top:*|' (instance-independent)")
            continue
        if parts[-1] == "clrn":
            parts = parts[:-1]
        entity = "canopen_master_top"
        ok = True
        for p in parts[1:-1]:
            m = re.fullmatch(r"(\w+):\*", p)
            if m is None:
                problems.append(f"{t}: '{p}' is not '<entity>:*' "
                                "(instance names must be wildcards)")
                ok = False
                break
            child = m.group(1).lower()
            if child not in units.get(entity, RtlUnit(Path(), "")).instances.values():
                problems.append(f"{t}: {entity} does not instantiate {child}")
                ok = False
                break
            entity = child
        if not ok:
            continue
        m = re.fullmatch(r"(\w+)\[(\*|\d+)\]|(\w+)", parts[-1])
        if m is None:
            problems.append(f"{t}: register '{parts[-1]}' unreadable")
            continue
        reg, idx = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), None)
        signals = units[entity].signals
        if reg.lower() not in signals:
            problems.append(f"{t}: {entity} has no signal {reg}")
            continue
        width = signals[reg.lower()]
        if idx is not None and (width is None or (idx != "*" and int(idx) >= width)):
            problems.append(f"{t}: {reg} has no bit {idx} (width {width})")
        covered.add((entity, reg.lower(), idx))
    for entity, u in units.items():
        for m in re.finditer(r"^\s*(\w+)\s*<=\s*\1\s*\(\s*0\s*\)\s*&\s*(\w+_i)\s*;", u.text,
                             re.I | re.M):
            reg = m.group(1).lower()
            if entity == "canopen_master_top" and m.group(2).lower() == "rst_n_i":
                continue
            if not ({(entity, reg, "0"), (entity, reg, "*")} & covered):
                problems.append(f"synchroniser {entity}.{reg} (from {m.group(2)}) has no "
                                "false path to its first flop in the SDC")
    if ("canopen_master_top", "rst_sync", "*") not in covered:
        problems.append("the reset synchroniser canopen_master_top.rst_sync is not covered")
    return problems


def test_sdc_names_real_registers():
    problems = sdc_problems(SDC.read_text(), _rtl_texts(rtl_sources(RTL_DIR / "files.f")))
    assert not problems, "ip/canopen_master.sdc:\n" + "\n".join(problems)
    assert len(_sdc_targets(SDC.read_text())) == 4


def test_sdc_checker_can_fail():
    sdc, files = SDC.read_text(), _rtl_texts(rtl_sources(RTL_DIR / "files.f"))
    # the RTL renames a synchroniser; the SDC names an instance; a third synchroniser appears
    bad_files = dict(files)
    bad_files["mcp2510_ctrl.vhd"] = files["mcp2510_ctrl.vhd"].replace("rx1_sync", "rx1_meta")
    bad_files["mcp2510_spi_master.vhd"] = _sub_once(
        files["mcp2510_spi_master.vhd"], r"(\n\s*signal miso_q\s*:)",
        "\n    signal cs_sync : std_logic_vector(1 downto 0);\\1")
    bad_files["mcp2510_spi_master.vhd"] = _sub_once(
        bad_files["mcp2510_spi_master.vhd"], r"(\n\s*miso_q <= to_X01\(spi_miso_i\);)",
        "\n            cs_sync <= cs_sync(0) & spi_miso_i;\\1")
    bad_sdc = sdc.replace("*canopen_master_top:*|mcp2510_ctrl:*|int_sync[0]",
                          "*canopen_master_top:*|mcp2510_ctrl:ctrl_inst|int_sync[0]")
    problems = sdc_problems(bad_sdc, bad_files)
    assert any("mcp2510_ctrl has no signal rx1_sync" in p for p in problems), problems
    assert any("'mcp2510_ctrl:ctrl_inst' is not '<entity>:*'" in p for p in problems), problems
    assert any(p.startswith("synchroniser mcp2510_spi_master.cs_sync") for p in problems)
    assert any(p.startswith("synchroniser mcp2510_ctrl.rx1_meta") for p in problems)
    # a wrong bit index and a wrong entity chain
    bad_sdc = sdc.replace("rx0_sync[0]", "rx0_sync[2]").replace(
        "*canopen_master_top:*|rst_sync", "*canopen_master_top:*|mcp2510_instr:*|rst_sync")
    problems = sdc_problems(bad_sdc, files)
    assert any("rx0_sync has no bit 2" in p for p in problems), problems
    assert any("canopen_master_top does not instantiate mcp2510_instr" in p for p in problems)
    assert "the reset synchroniser canopen_master_top.rst_sync is not covered" in problems


# ================================================================= Nios II driver package
SBT_STUBS = _stubs("create_driver", "set_sw_property", "add_sw_property", "add_sw_setting",
                   "set_sw_setting_property")


def sw_problems(calls: list[list[str]], hw_module: dict[str, str], tcl_dir: Path,
                sw_dir: Path) -> list[str]:
    """The recorded SBT calls against the component and the files of sw/."""
    problems = []
    if not calls or calls[0][0] != "create_driver":
        problems.append("create_driver must be the first command")
    if [c[0] for c in calls].count("create_driver") != 1:
        problems.append("exactly one create_driver expected")
    setp = {c[1]: c[2] for c in calls if c[0] == "set_sw_property" and len(c) == 3}
    addp: dict[str, list[str]] = {}
    for c in calls:
        if c[0] == "add_sw_property" and len(c) == 3:
            addp.setdefault(c[1], []).append(c[2])
    if setp.get("hw_class_name") != hw_module.get("NAME"):
        problems.append(f"hw_class_name {setp.get('hw_class_name')}, _hw.tcl NAME "
                        f"{hw_module.get('NAME')}")
    if setp.get("version") != hw_module.get("VERSION"):
        problems.append(f"version {setp.get('version')}, _hw.tcl VERSION "
                        f"{hw_module.get('VERSION')}")

    def vkey(v: str) -> tuple[int, ...]:
        return tuple(int(x) for x in re.findall(r"\d+", v))

    mcv = setp.get("min_compatible_hw_version")
    if mcv is None or vkey(mcv) > vkey(hw_module.get("VERSION", "0")):
        problems.append(f"min_compatible_hw_version {mcv} excludes the component version "
                        f"{hw_module.get('VERSION')}")
    if "HAL" not in [s.upper() for s in addp.get("supported_bsp_type", [])]:
        problems.append("supported_bsp_type HAL missing")
    if not setp.get("bsp_subdirectory"):
        problems.append("bsp_subdirectory missing")
    listed = {}
    for prop in ("c_source", "include_source"):
        for rel in addp.get(prop, []):
            path = (tcl_dir / rel).resolve()
            listed[path] = prop
            if not path.is_file():
                problems.append(f"{prop} {rel}: no such file")
            elif prop == "c_source" and path.suffix != ".c":
                problems.append(f"c_source {rel} is not a .c file")
            elif prop == "include_source" and path.suffix != ".h":
                problems.append(f"include_source {rel} is not a .h file")
    on_disk = sorted(p.resolve() for d in (sw_dir, sw_dir / "include") if d.is_dir()
                     for p in d.iterdir() if p.suffix in {".c", ".h"})
    if not on_disk:
        problems.append(f"no C driver files in {sw_dir}")
    problems += [f"{p.relative_to(sw_dir.parent)} is not in the driver package"
                 for p in on_disk if p not in listed]
    incdirs = [(tcl_dir / d).resolve() for d in addp.get("include_directory", [])]
    for path in listed:
        if not path.is_file():
            continue
        for inc in re.findall(r'^\s*#\s*include\s+"([^"]+)"', path.read_text(), re.M):
            candidates = [path.parent / inc, *(d / inc for d in incdirs)]
            hit = [c.resolve() for c in candidates if c.resolve() in listed]
            if not hit:
                problems.append(f'{path.name}: #include "{inc}" is not a packaged header on '
                                "its own folder or an include_directory")
    return problems


def test_sw_tcl_driver_package(tmp_path):
    calls = _run_tcl(tmp_path, SBT_STUBS, SW_TCL)
    comp = parse_component(HW_TCL.read_text())
    problems = sw_problems(calls, comp.module, SW_TCL.parent, SW_DIR)
    assert not problems, "ip/canopen_master_sw.tcl:\n" + "\n".join(problems)
    assert {c[2] for c in calls if c[:2] == ["add_sw_property", "c_source"]} == {
        "../sw/canopen_master.c"}


def test_sw_tcl_checker_can_fail(tmp_path):
    comp = parse_component(HW_TCL.read_text())
    text = SW_TCL.read_text()
    bad = _sub_once(text, r"hw_class_name canopen_master$", "hw_class_name canopen_mastr")
    bad = _sub_once(bad, r"^add_sw_property include_directory \.\./sw/include\n", "")
    bad = _sub_once(bad, r"min_compatible_hw_version 1\.0", "min_compatible_hw_version 2.0")
    bad = _sub_once(bad, r"c_source \.\./sw/canopen_master\.c", "c_source ../sw/canopen_mastr.c")
    doctored = tmp_path / "ip" / "canopen_master_sw.tcl"
    doctored.parent.mkdir()
    doctored.write_text(bad)
    shutil.copytree(SW_DIR, tmp_path / "sw")
    (tmp_path / "sw" / "canopen_master_extra.c").write_text("int x;\n")
    calls = _run_tcl(tmp_path, SBT_STUBS, doctored)
    problems = sw_problems(calls, comp.module, doctored.parent, tmp_path / "sw")
    assert any(p.startswith("hw_class_name canopen_mastr") for p in problems), problems
    assert any("excludes the component version" in p for p in problems), problems
    assert "c_source ../sw/canopen_mastr.c: no such file" in problems, problems
    assert "sw/canopen_master_extra.c is not in the driver package" in problems, problems
    assert any('#include "canopen_master_regs.h"' in p for p in problems), problems


# ====================================================================== Quartus project
QUARTUS_STUBS = _stubs("project_new", "project_open", "project_close", "export_assignments",
                       "set_global_assignment", "set_instance_assignment",
                       "set_location_assignment", "remove_all_global_assignments") + """
package provide ::quartus::project 1.0
proc project_exists {name} { return 0 }
"""
#: F484 ball rows (no I, O, Q, S, X, Z) and columns 1..22
F484_ROWS = ["A", "B", "C", "D", "E", "F", "G", "H", "J", "K", "L", "M", "N", "P", "R", "T", "U",
             "V", "W", "Y", "AA", "AB"]
#: ports of the stand-alone top that leave the board (the Avalon and debug ports do not)
BOARD_PORT_RE = re.compile(r"^(clk_i|rst_n_i|spi_\w+|mcp_\w+)$")


def _option(call: list[str], name: str) -> str | None:
    return call[call.index(name) + 1] if name in call[:-1] else None


def _value(call: list[str]) -> str:
    """The positional argument of a Quartus assignment call (options are '-x value' pairs)."""
    words, rest = call[1:], []
    while words:
        if words[0].startswith("-") and len(words) > 1:
            words = words[2:]
        else:
            rest.append(words.pop(0))
    assert len(rest) == 1, f"cannot read {call}"
    return rest[0]


def quartus_problems(calls: list[list[str]], project_dir: Path, order: list[Path],
                     ports, constraints: Path = ROOT / "constraints") -> list[str]:
    problems = []
    glob = [c for c in calls if c[0] == "set_global_assignment"]
    single = {_option(c, "-name"): _value(c) for c in glob}
    for name, value in (("FAMILY", FAMILY), ("DEVICE", DEVICE),
                        ("TOP_LEVEL_ENTITY", "canopen_master_top")):
        if single.get(name) != value:
            problems.append(f"{name} = {single.get(name)}, expected {value}")
    # VHDL-93 RTL: VHDL_1993, or no assignment (Quartus' default, what edalize writes when no
    # file is vhdlSource-2008)
    if single.get("VHDL_INPUT_VERSION", "VHDL_1993") != "VHDL_1993":
        problems.append(f"VHDL_INPUT_VERSION = {single.get('VHDL_INPUT_VERSION')}, "
                        "expected VHDL_1993")
    vhdl = [c for c in glob if _option(c, "-name") == "VHDL_FILE"]
    files = [(project_dir / _value(c)).resolve() for c in vhdl]
    if files != [p.resolve() for p in order]:
        problems.append(f"VHDL_FILE list {[f.name for f in files]} != rtl/files.f "
                        f"{[p.name for p in order]}")
    problems += [f"VHDL_FILE {_value(c)} without -library canopen_master"
                 for c in vhdl if _option(c, "-library") != "canopen_master"]
    sdc = [(project_dir / _value(c)).resolve() for c in glob
           if _option(c, "-name") == "SDC_FILE"]
    if sdc != [(constraints / "ep3c80_reference.sdc").resolve()]:
        problems.append(f"SDC_FILE {sdc}")
    locs = {_option(c, "-to"): c[1] for c in calls if c[0] == "set_location_assignment"}
    want = [f"{p.name}[{i}]" if p.vector else p.name for p in ports
            if BOARD_PORT_RE.match(p.name) for i in (range(p.width) if p.vector else [0])]
    problems += [f"no location for {w}" for w in want if w not in locs]
    problems += [f"location for {t}, which is not a board pin of the top" for t in locs
                 if t not in want]
    for target, pin in locs.items():
        m = re.fullmatch(r"PIN_([A-Z]{1,2})(\d+)", pin)
        if m is None or m.group(1) not in F484_ROWS or not 1 <= int(m.group(2)) <= 22:
            problems.append(f"{target}: {pin} is not an F484 ball name")
    used = list(locs.values())
    problems += [f"ball {b} used twice" for b in sorted(set(used)) if used.count(b) > 1]
    iostd = {_option(c, "-to") for c in calls if c[0] == "set_instance_assignment"
             and _option(c, "-name") == "IO_STANDARD"}
    problems += [f"no IO_STANDARD for {w}" for w in want if w not in iostd]
    return problems


def test_quartus_project_script(tmp_path):
    project = tmp_path / "qproj"
    calls = _run_tcl(tmp_path, QUARTUS_STUBS, QUARTUS_TCL, str(project))
    assert ["project_new", "canopen_master"] in calls
    assert calls[-2:] == [["export_assignments"], ["project_close"]], calls[-2:]
    problems = quartus_problems(calls, project, rtl_sources(RTL_DIR / "files.f"),
                                entity_interface(TOP_VHD.read_text())[1])
    assert not problems, "scripts/quartus_project.tcl:\n" + "\n".join(problems)
    text = PINS_TCL.read_text()
    assert "PLACEHOLDER" in text and "Replace every set_location_assignment" in text


def test_fusesoc_quartus_target_setup(tmp_path):
    """``fusesoc run --setup --target quartus`` (no Quartus needed): the project script edalize
    writes makes the same assignments as scripts/quartus_project.tcl (run with stubs)."""
    build = tmp_path / "build"
    res = _fusesoc("run", "--setup", "--build-root", str(build), "--target", "quartus", VLNV,
                   cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    work = build / "canopen_master_ip_canopen_master_1.0" / "quartus-quartus"
    script = work / "canopen_master_ip_canopen_master_1_0.tcl"
    src = work / "src" / "canopen_master_ip_canopen_master_1.0"
    calls = _run_tcl(tmp_path, QUARTUS_STUBS, script, cwd=work)
    order = [src / p.relative_to(ROOT) for p in rtl_sources(RTL_DIR / "files.f")]
    problems = quartus_problems(calls, work, order, entity_interface(TOP_VHD.read_text())[1],
                                constraints=src / "constraints")
    assert not problems, "fusesoc quartus target:\n" + "\n".join(problems)


def test_quartus_checker_can_fail(tmp_path):
    """A repository copy with a doctored files.f and pin file; and a missing file in files.f."""
    copy = tmp_path / "repo"
    for d in ("rtl", "constraints", "scripts"):
        shutil.copytree(ROOT / d, copy / d)
    files_f = copy / "rtl" / "files.f"
    files_f.write_text(_sub_once(files_f.read_text(), r"^canopen_pkg\.vhd\n", ""))
    pins = copy / "constraints" / "ep3c80_reference_pins.tcl"
    text = _sub_once(pins.read_text(), r"PIN_AB16 -to spi_cs_n_o", "PIN_AB15 -to spi_cs_n_o")
    text = _sub_once(text, r"PIN_AA16 -to spi_sck_o", "PIN_AC16 -to spi_sck_o")
    script = copy / "scripts" / "quartus_project.tcl"
    script.write_text(_sub_once(script.read_text(), r"VHDL_INPUT_VERSION VHDL_1993",
                                "VHDL_INPUT_VERSION VHDL_2008"))
    pins.write_text(_sub_once(text, r"^set_location_assignment PIN_AB8  -to mcp_reset_n_o\n", ""))
    project = tmp_path / "qproj"
    calls = _run_tcl(tmp_path, QUARTUS_STUBS, copy / "scripts" / "quartus_project.tcl",
                     str(project))
    problems = quartus_problems(calls, project, rtl_sources(RTL_DIR / "files.f"),
                                entity_interface(TOP_VHD.read_text())[1])
    assert any(p.startswith("VHDL_FILE list") for p in problems), problems
    assert "ball PIN_AB15 used twice" in problems, problems
    assert "spi_sck_o: PIN_AC16 is not an F484 ball name" in problems, problems
    assert "no location for mcp_reset_n_o" in problems, problems
    assert "VHDL_INPUT_VERSION = VHDL_2008, expected VHDL_1993" in problems, problems
    files_f.write_text(files_f.read_text() + "no_such_file.vhd\n")
    with pytest.raises(RuntimeError, match="rtl/files.f lists no_such_file.vhd"):
        _run_tcl(tmp_path, QUARTUS_STUBS, copy / "scripts" / "quartus_project.tcl", str(project))


# ============================================================ Platform Designer system
QSYS_STUBS = _stubs("set_project_property", "add_instance", "set_instance_parameter_value",
                    "add_connection", "set_connection_parameter_value", "add_interface",
                    "set_interface_property", "save_system") + "\npackage provide qsys 13.1\n"
#: interface kinds each end of a connection must have on the canopen_master side
QSYS_CONNECTION_KIND = {"clock": "clock", "reset": "reset", "avalon": "avalon",
                        "interrupt": "interrupt"}
#: address spans of the other slaves of the reference system (bytes)
OTHER_SPANS = {"cpu.jtag_debug_module": 2048, "jtag_uart.avalon_jtag_slave": 8}


def qsys_problems(calls: list[list[str]], comp) -> list[str]:
    problems = []
    instances = {c[1]: c[2:] for c in calls if c[0] == "add_instance"}
    ours = [n for n, rest in instances.items() if rest and rest[0] == comp.module["NAME"]]
    if len(ours) != 1:
        return [f"expected one instance of {comp.module['NAME']}, found {ours}"]
    inst = ours[0]
    if instances[inst][1:2] != [comp.module["VERSION"]]:
        problems.append(f"{inst}: version {instances[inst][1:2]}, _hw.tcl VERSION "
                        f"{comp.module['VERSION']}")
    params = {c[2]: c[3] for c in calls if c[0] == "set_instance_parameter_value" and c[1] == inst}
    problems += [f"{inst}: parameter {p} is not a parameter of the component"
                 for p in params if p not in comp.params]
    if "CLK_FREQ_HZ" in params:
        problems.append(f"{inst}: CLK_FREQ_HZ is set by the clock (SYSTEM_INFO), not by hand")
    used: dict[str, list[str]] = {}
    conns = [c[1:3] for c in calls if c[0] == "add_connection"]
    for a, b in conns:
        for end, other in ((a, b), (b, a)):
            if end.split(".")[0] == inst:
                iface = end.split(".", 1)[1]
                used.setdefault(iface, []).append(other)
                if iface not in comp.interfaces:
                    problems.append(f"connection {a} -> {b}: {inst} has no interface {iface}")
    exports = {c[1]: c[3] for c in calls if c[0] == "set_interface_property" and
               c[2] == "EXPORT_OF"}
    for name, target in exports.items():
        if target.split(".")[0] == inst:
            iface = target.split(".", 1)[1]
            used.setdefault(iface, []).append(f"export {name}")
            if iface not in comp.interfaces:
                problems.append(f"export {name}: {inst} has no interface {iface}")
    for iface, (kind, _) in comp.interfaces.items():
        if iface == "debug":
            continue
        if iface not in used:
            problems.append(f"interface {iface} ({kind}) is neither connected nor exported")
        elif kind == "conduit" and not any(u.startswith("export ") for u in used[iface]):
            problems.append(f"conduit {iface} is not exported")
    cparams = {(c[1], c[2]): c[3] for c in calls if c[0] == "set_connection_parameter_value"}
    addr_w = next(int(p.width) for p in comp.ports if p.role == "address")
    span = {f"{inst}.s0": 4 * 2 ** addr_w, **OTHER_SPANS}
    ram = [n for n, rest in instances.items() if rest[0] == "altera_avalon_onchip_memory2"]
    for r in ram:
        size = next(c[3] for c in calls if c[:3] == ["set_instance_parameter_value", r,
                                                    "memorySize"])
        span[f"{r}.s1"] = int(float(size))
    ranges = []
    for (conn, key), value in cparams.items():
        if key != "baseAddress" or not conn.startswith("cpu.data_master/"):
            continue
        slave = conn.split("/", 1)[1]
        base = int(value, 0)
        if slave not in span:
            problems.append(f"{slave}: span unknown to the checker")
            continue
        if base % span[slave]:
            problems.append(f"{slave}: base 0x{base:x} not aligned to its span 0x{span[slave]:x}")
        ranges.append((base, base + span[slave], slave))
    if not any(s == f"{inst}.s0" for *_, s in ranges):
        problems.append(f"{inst}.s0 has no base address on cpu.data_master")
    ranges.sort()
    problems += [f"{a[2]} and {b[2]} overlap" for a, b in zip(ranges, ranges[1:]) if b[0] < a[1]]
    irqs = {conn: int(v) for (conn, key), v in cparams.items() if key == "irqNumber"}
    if f"cpu.d_irq/{inst}.irq" not in irqs:
        problems.append(f"{inst}.irq has no IRQ number on cpu.d_irq")
    nums = list(irqs.values())
    problems += [f"IRQ {n} used twice" for n in sorted(set(nums)) if nums.count(n) > 1]
    if not any(c[0] == "save_system" for c in calls):
        problems.append("the system is never saved")
    return problems


def test_qsys_reference_system(tmp_path):
    calls = _run_tcl(tmp_path, QSYS_STUBS, QSYS_TCL)
    comp = parse_component(HW_TCL.read_text())
    problems = qsys_problems(calls, comp)
    assert not problems, "ip/reference_system/nios2_canopen_qsys.tcl:\n" + "\n".join(problems)
    kinds = {end.split(".")[0] for c in calls if c[0] == "add_connection" for end in c[1:3]}
    assert {"cpu", "onchip_ram", "jtag_uart", "canopen", "clk_0"} <= kinds
    assert ["set_project_property", "DEVICE", DEVICE] in calls


def test_qsys_checker_can_fail(tmp_path):
    comp = parse_component(HW_TCL.read_text())
    text = QSYS_TCL.read_text()
    bad = text.replace("canopen.s0", "canopen.avs")
    bad = _sub_once(bad, r"baseAddress 0x00011000", "baseAddress 0x00010400")
    bad = _sub_once(bad, r"irqNumber 1", "irqNumber 0")
    bad = _sub_once(bad, r"^set_interface_property mcp2510 EXPORT_OF canopen\.mcp2510\n", "")
    bad = _sub_once(bad, r"(set_instance_parameter_value canopen SPI_SCLK_HZ)",
                    "set_instance_parameter_value canopen SPI_HZ 1\n\\1")
    doctored = tmp_path / "system.tcl"
    doctored.write_text(bad)
    problems = qsys_problems(_run_tcl(tmp_path, QSYS_STUBS, doctored), comp)
    assert any("canopen has no interface avs" in p for p in problems), problems
    assert "canopen.s0 has no base address on cpu.data_master" in problems, problems
    assert "IRQ 0 used twice" in problems, problems
    assert "interface mcp2510 (conduit) is neither connected nor exported" in problems
    assert "canopen: parameter SPI_HZ is not a parameter of the component" in problems
    bad = _sub_once(text, r"baseAddress 0x00011000", "baseAddress 0x00010008")
    doctored.write_text(bad)
    problems = qsys_problems(_run_tcl(tmp_path, QSYS_STUBS, doctored), comp)
    assert "canopen.s0 and jtag_uart.avalon_jtag_slave overlap" in problems, problems


# ================================================================ the Nios II example
DOC = ROOT / "docs" / "integration.md"
EXAMPLE_MARK = "<!-- example: compiled against sw/ by tb/test_integration_kit.py"
#: the parts of the Nios II HAL the example uses, declared as the Nios II HAL declares them
NIOS_STUBS = {
    "io.h": "#include <stdint.h>\n"
            "#define IORD(base, reg) (*(volatile uint32_t *)((uintptr_t)(base) + 4u * (reg)))\n"
            "#define IOWR(base, reg, data) \\\n"
            "    (*(volatile uint32_t *)((uintptr_t)(base) + 4u * (reg)) = (data))\n",
    "system.h": "#define CANOPEN_BASE 0x10000\n#define CANOPEN_IRQ 0\n"
                "#define CANOPEN_IRQ_INTERRUPT_CONTROLLER_ID 0\n",
    "sys/alt_irq.h": "typedef unsigned int alt_u32;\n"
                     "typedef void (*alt_isr_func)(void *isr_context);\n"
                     "int alt_ic_isr_register(alt_u32 ic_id, alt_u32 irq, alt_isr_func isr,\n"
                     "                        void *isr_context, void *flags);\n"
                     "int alt_ic_irq_enable(alt_u32 ic_id, alt_u32 irq);\n"
                     "int alt_ic_irq_disable(alt_u32 ic_id, alt_u32 irq);\n",
    "unistd.h": "int usleep(unsigned int us);\n",
}


def doc_example(text: str) -> str:
    """The C block that follows the example marker in docs/integration.md."""
    at = text.index(EXAMPLE_MARK)
    m = re.search(r"```c\n(.*?)```", text[at:], re.S)
    assert m, "no ```c block after the example marker"
    return m.group(1)


def _compile_example(tmp_path: Path, code: str) -> subprocess.CompletedProcess:
    stubs = tmp_path / "nios2_stubs"
    for name, body in NIOS_STUBS.items():
        (stubs / name).parent.mkdir(parents=True, exist_ok=True)
        (stubs / name).write_text(body)
    src = tmp_path / "main.c"
    src.write_text(code)
    return subprocess.run(
        [shutil.which("gcc") or "gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic",
         "-fsyntax-only", f"-I{stubs}", f"-I{SW_DIR}", f"-I{SW_DIR / 'include'}", str(src)],
        capture_output=True, text=True, timeout=60, check=False)


def test_doc_nios2_example_compiles(tmp_path):
    res = _compile_example(tmp_path, doc_example(DOC.read_text()))
    assert res.returncode == 0, res.stderr


def test_doc_nios2_example_check_can_fail(tmp_path):
    """A HAL function that does not exist, and a callback of the wrong type, are errors."""
    code = doc_example(DOC.read_text())
    res = _compile_example(tmp_path, code.replace("cm_irq_handler(&cm)", "cm_irq_service(&cm)"))
    assert res.returncode != 0 and "cm_irq_service" in res.stderr, res.stderr
    res = _compile_example(tmp_path, code.replace(
        "static uint32_t cm_rd(cm_ctx_t *ctx, uint32_t word_addr)",
        "static uint16_t cm_rd(cm_ctx_t *ctx, uint32_t word_addr)"))
    assert res.returncode != 0 and "cm_setup" in res.stderr, res.stderr
