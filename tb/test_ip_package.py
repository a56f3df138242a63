"""Checks of the Platform Designer component ``ip/canopen_master_hw.tcl`` (no simulator).

The component description is written by hand, so nothing keeps it in step with the VHDL except
this file. It parses the ``_hw.tcl`` with regular expressions and compares it with the entity
``canopen_master_top`` (generic and port lists, also parsed with regular expressions) and with
``rtl/files.f``:

* every port of the entity is mapped by exactly one ``add_interface_port`` with the same
  direction and width, and every ``add_interface_port`` names a real port of a declared interface;
* every generic is an ``add_parameter`` of the same name, type INTEGER, the same default and the
  same allowed range (VHDL ``positive``/``natural``/``range a to b``), or type BOOLEAN with the
  same default (VHDL ``boolean``), with ``HDL_PARAMETER true``;
* the QUARTUS_SYNTH and SIM_VHDL filesets list exactly ``rtl/files.f``, in order, with the top
  level ``canopen_master_top``;
* the Avalon-MM slave's address width equals ``avs_address_i``'s, it uses word addressing, fixed
  read latency 2 (registered inputs and read data) and no waitrequest/readdatavalid; the data
  width matches the byte enables;
* every ``associatedClock``/``associatedReset``/``associatedAddressablePoint`` names an interface
  of the right type.

Each check is a function returning its findings; ``test_checks_can_fail`` feeds doctored copies
to prove they are reported. When ``tclsh`` is installed, ``test_hw_tcl_runs_in_tclsh`` also
sources the file with stub Platform Designer commands: it proves the file is valid Tcl, that the
regex parser reads the same commands Tcl executes, and that the validation callback rejects bad
parameter combinations. Neither replaces loading the component in Platform Designer.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tb.tblib.runner import ROOT, RTL_DIR, rtl_sources

HW_TCL = ROOT / "ip" / "canopen_master_hw.tcl"
TOP_VHD = RTL_DIR / "canopen_master_top.vhd"
FILES_F = RTL_DIR / "files.f"
TOP_ENTITY = "canopen_master_top"
FILESETS = ("QUARTUS_SYNTH", "SIM_VHDL")
INT_MAX = 2**31 - 1
#: allowed range of the VHDL integer subtypes the generics use
VHDL_SUBTYPES = {"positive": (1, INT_MAX), "natural": (0, INT_MAX), "integer": (-(2**31), INT_MAX)}
PD_DIRECTION = {"in": "Input", "out": "Output", "inout": "Bidir"}


# ---------------------------------------------------------------------------- VHDL (entity)
@dataclass(frozen=True)
class Generic:
    name: str
    subtype: str
    default: int | bool
    lo: int
    hi: int


@dataclass(frozen=True)
class Port:
    name: str
    direction: str  # in / out / inout
    width: int
    vector: bool


_GENERIC_RE = re.compile(
    r"^(?P<names>\w+(?:\s*,\s*\w+)*)\s*:\s*(?P<type>positive|natural|integer)"
    r"(?:\s+range\s+(?P<lo>-?[\d_]+)\s+to\s+(?P<hi>-?[\d_]+))?\s*:=\s*(?P<default>-?[\d_]+)$",
    re.IGNORECASE,
)
_BOOL_GENERIC_RE = re.compile(
    r"^(?P<names>\w+(?:\s*,\s*\w+)*)\s*:\s*boolean\s*:=\s*(?P<default>true|false)$",
    re.IGNORECASE,
)
_PORT_RE = re.compile(
    r"^(?P<names>\w+(?:\s*,\s*\w+)*)\s*:\s*(?P<dir>in|out|inout)\s+"
    r"(?P<type>std_u?logic)(?P<vec>_vector\s*\(\s*(?P<hi>\d+)\s+downto\s+(?P<lo>\d+)\s*\))?$",
    re.IGNORECASE,
)


def _int(text: str) -> int:
    return int(text.replace("_", ""))


def _paren_body(text: str, keyword: str) -> str:
    """Text between the parentheses that follow ``keyword`` (balanced)."""
    m = re.search(rf"\b{keyword}\s*\(", text, re.IGNORECASE)
    if m is None:
        return ""
    depth, start = 1, m.end()
    for i in range(start, len(text)):
        depth += {"(": 1, ")": -1}.get(text[i], 0)
        if depth == 0:
            return text[start:i]
    raise AssertionError(f"unbalanced parentheses after '{keyword}'")


def _declarations(body: str) -> list[str]:
    """Split a generic/port list at the semicolons outside parentheses."""
    out, depth, cur = [], 0, []
    for ch in body:
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if ch == ";" and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return [" ".join(d.split()) for d in out if d.strip()]


def entity_interface(text: str, entity: str = TOP_ENTITY) -> tuple[list[Generic], list[Port]]:
    """Generics and ports of ``entity`` in ``text`` (VHDL). Unparsable declarations raise."""
    text = re.sub(r"--[^\n]*", "", text)
    m = re.search(rf"\bentity\s+{entity}\s+is\b(.*?)\bend\s+(?:entity\b|{entity}\b)", text,
                  re.IGNORECASE | re.DOTALL)
    assert m, f"entity {entity} not found"
    body = m[1]
    port_at = re.search(r"\bport\s*\(", body, re.IGNORECASE)
    generic_part = body[:port_at.start()] if port_at else body
    generics: list[Generic] = []
    for decl in _declarations(_paren_body(generic_part, "generic")):
        b = _BOOL_GENERIC_RE.match(decl)
        if b is not None:
            generics += [Generic(n.strip(), "boolean", b["default"].lower() == "true", 0, 1)
                         for n in b["names"].split(",")]
            continue
        g = _GENERIC_RE.match(decl)
        if g is None:
            raise AssertionError(f"generic declaration this checker cannot read: {decl!r}")
        lo, hi = VHDL_SUBTYPES[g["type"].lower()]
        if g["lo"] is not None:
            lo, hi = _int(g["lo"]), _int(g["hi"])
        generics += [Generic(n.strip(), g["type"].lower(), _int(g["default"]), lo, hi)
                     for n in g["names"].split(",")]
    ports: list[Port] = []
    for decl in _declarations(_paren_body(body[port_at.start():], "port") if port_at else ""):
        p = _PORT_RE.match(decl)
        if p is None:
            raise AssertionError(f"port declaration this checker cannot read: {decl!r}")
        vector = p["vec"] is not None
        width = _int(p["hi"]) - _int(p["lo"]) + 1 if vector else 1
        ports += [Port(n.strip(), p["dir"].lower(), width, vector)
                  for n in p["names"].split(",")]
    return generics, ports


# ---------------------------------------------------------------------------- Tcl (_hw.tcl)
_TOKEN_RE = re.compile(r'\{[^{}]*\}|"(?:[^"\\]|\\.)*"|[^\s{}"]+')


def _unquote(token: str) -> str:
    if len(token) >= 2 and (token[0], token[-1]) in {("{", "}"), ('"', '"')}:
        return token[1:-1]
    return token


def tcl_commands(text: str) -> list[list[str]]:
    """Top-level commands of a Tcl file as word lists (bodies of ``proc`` are skipped)."""
    text = re.sub(r"\\\n\s*", " ", text)
    commands, depth = [], 0
    for line in text.splitlines():
        stripped = line.strip()
        if depth == 0 and stripped and not stripped.startswith("#"):
            commands.append([_unquote(t) for t in _TOKEN_RE.findall(stripped)])
        if not stripped.startswith("#"):
            depth += stripped.count("{") - stripped.count("}")
    return commands


@dataclass(frozen=True)
class PortMap:
    interface: str
    port: str
    role: str
    direction: str
    width: str  # as written: a number, or an expression the checker reports


@dataclass
class Fileset:
    kind: str
    props: dict[str, str] = field(default_factory=dict)
    files: list[list[str]] = field(default_factory=list)  # [output, type, source, path, *attrs]


@dataclass
class Component:
    module: dict[str, str] = field(default_factory=dict)
    interfaces: dict[str, tuple[str, str]] = field(default_factory=dict)  # name -> (type, dir)
    iface_props: dict[str, dict[str, str]] = field(default_factory=dict)
    ports: list[PortMap] = field(default_factory=list)
    port_props: dict[str, dict[str, str]] = field(default_factory=dict)
    params: dict[str, dict[str, str]] = field(default_factory=dict)
    filesets: dict[str, Fileset] = field(default_factory=dict)


def parse_component(text: str) -> Component:
    comp, fileset = Component(), None
    for cmd in tcl_commands(text):
        name, args = cmd[0], cmd[1:]
        if name == "set_module_property" and len(args) >= 2:
            comp.module[args[0]] = args[1]
        elif name == "add_interface" and len(args) >= 3:
            comp.interfaces[args[0]] = (args[1], args[2])
            comp.iface_props.setdefault(args[0], {})
        elif name == "set_interface_property" and len(args) >= 3:
            comp.iface_props.setdefault(args[0], {})[args[1]] = args[2]
        elif name == "add_interface_port" and len(args) >= 5:
            comp.ports.append(PortMap(*args[:5]))
        elif name == "set_port_property" and len(args) >= 3:
            comp.port_props.setdefault(args[0], {})[args[1]] = args[2]
        elif name == "add_parameter" and len(args) >= 2:
            comp.params[args[0]] = {"TYPE": args[1]}
            if len(args) >= 3:
                comp.params[args[0]]["DEFAULT_VALUE"] = args[2]
        elif name == "set_parameter_property" and len(args) >= 3:
            comp.params.setdefault(args[0], {})[args[1]] = args[2]
        elif name == "add_fileset" and len(args) >= 2:
            fileset = comp.filesets[args[0]] = Fileset(args[1])
        elif name == "set_fileset_property" and len(args) >= 3 and args[0] in comp.filesets:
            comp.filesets[args[0]].props[args[1]] = args[2]
        elif name == "add_fileset_file":
            if fileset is None:
                raise AssertionError(f"add_fileset_file before any add_fileset: {cmd}")
            fileset.files.append(args)
    return comp


# ------------------------------------------------------------------------------- the checks
def port_problems(comp: Component, ports: list[Port]) -> list[str]:
    """Entity ports not mapped exactly once, with the wrong direction or width; mapped names
    that are no port; ports on undeclared interfaces."""
    by_name = {p.name.lower(): p for p in ports}
    problems = []
    for p in ports:
        maps = [m for m in comp.ports if m.port.lower() == p.name.lower()]
        if len(maps) != 1:
            problems.append(f"port {p.name} is in {len(maps)} add_interface_port lines "
                            "(expected exactly 1)")
            continue
        m = maps[0]
        if m.direction != PD_DIRECTION[p.direction]:
            problems.append(f"port {p.name}: direction {m.direction}, entity says {p.direction}")
        if m.width != str(p.width):
            problems.append(f"port {p.name}: width {m.width}, entity says {p.width}")
        if p.vector and p.width == 1 and (
                comp.port_props.get(p.name, {}).get("VHDL_TYPE") != "STD_LOGIC_VECTOR"):
            problems.append(f"port {p.name} is a 1-bit std_logic_vector: needs "
                            "set_port_property VHDL_TYPE STD_LOGIC_VECTOR")
    for m in comp.ports:
        if m.port.lower() not in by_name:
            problems.append(f"add_interface_port {m.interface} {m.port}: no such port in "
                            f"entity {TOP_ENTITY}")
        if m.interface not in comp.interfaces:
            problems.append(f"add_interface_port {m.interface} {m.port}: interface "
                            f"{m.interface} is not declared with add_interface")
    roles = [(m.interface, m.role) for m in comp.ports]
    problems += [f"interface {i} uses role {r} twice" for i, r in sorted(set(roles))
                 if roles.count((i, r)) > 1]
    return problems


def generic_problems(comp: Component, generics: list[Generic]) -> list[str]:
    """Generics without a matching parameter (type, default, range, HDL_PARAMETER), and HDL
    parameters that are no generic."""
    problems = []
    names = {g.name for g in generics}
    for g in generics:
        p = comp.params.get(g.name)
        if p is None:
            problems.append(f"generic {g.name} has no add_parameter {g.name}")
            continue
        if g.subtype == "boolean":
            if p.get("TYPE", "").upper() != "BOOLEAN":
                problems.append(f"parameter {g.name}: TYPE {p.get('TYPE')}, expected BOOLEAN")
            if p.get("DEFAULT_VALUE", "").lower() != str(g.default).lower():
                problems.append(f"parameter {g.name}: default {p.get('DEFAULT_VALUE')}, "
                                f"generic default {str(g.default).lower()}")
            if p.get("HDL_PARAMETER", "false").lower() not in {"true", "1"}:
                problems.append(f"parameter {g.name} is not HDL_PARAMETER true")
            continue
        if p.get("TYPE", "").upper() != "INTEGER":
            problems.append(f"parameter {g.name}: TYPE {p.get('TYPE')}, expected INTEGER")
        if p.get("DEFAULT_VALUE") != str(g.default):
            problems.append(f"parameter {g.name}: default {p.get('DEFAULT_VALUE')}, "
                            f"generic default {g.default}")
        if p.get("ALLOWED_RANGES") != f"{g.lo}:{g.hi}":
            problems.append(f"parameter {g.name}: ALLOWED_RANGES {p.get('ALLOWED_RANGES')}, "
                            f"generic range {g.lo}:{g.hi}")
        if p.get("HDL_PARAMETER", "false").lower() not in {"true", "1"}:
            problems.append(f"parameter {g.name} is not HDL_PARAMETER true")
    problems += [f"HDL parameter {n} is no generic of {TOP_ENTITY}"
                 for n, p in comp.params.items()
                 if p.get("HDL_PARAMETER", "false").lower() in {"true", "1"} and n not in names]
    return problems


#: non-VHDL files each fileset must carry: output name -> (type, source path)
FILESET_EXTRAS = {"QUARTUS_SYNTH": {"canopen_master.sdc": ("SDC", "canopen_master.sdc")},
                  "SIM_VHDL": {}}


def fileset_problems(comp: Component, order: list[Path]) -> list[str]:
    """Each fileset must list ``order`` (rtl/files.f) exactly, as VHDL from ../rtl/, with the
    top level file and entity marked, plus exactly its ``FILESET_EXTRAS`` (the component SDC)."""
    expected = [p.name for p in order]
    problems = []
    for name in FILESETS:
        fs = comp.filesets.get(name)
        if fs is None:
            problems.append(f"fileset {name} missing")
            continue
        if fs.kind != name:
            problems.append(f"fileset {name} has kind {fs.kind}")
        if fs.props.get("TOP_LEVEL") != TOP_ENTITY:
            problems.append(f"fileset {name}: TOP_LEVEL {fs.props.get('TOP_LEVEL')}, "
                            f"expected {TOP_ENTITY}")
        vhdl = [f for f in fs.files if len(f) > 1 and f[1] == "VHDL"]
        extras = {f[0]: (f[1], f[3]) for f in fs.files
                  if len(f) >= 4 and f[1] != "VHDL" and f[2] == "PATH"}
        if len(extras) + len(vhdl) != len(fs.files):
            problems.append(f"fileset {name}: unreadable add_fileset_file lines")
        if extras != FILESET_EXTRAS[name]:
            problems.append(f"fileset {name}: non-VHDL files {extras}, expected "
                            f"{FILESET_EXTRAS[name]}")
        listed = [f[0] for f in vhdl]
        if listed != expected:
            problems.append(f"fileset {name} lists {listed}, rtl/files.f has {expected}")
        for f in vhdl:
            if len(f) < 4 or f[1:3] != ["VHDL", "PATH"] or f[3] != f"../rtl/{f[0]}":
                problems.append(f"fileset {name}: expected '{f[0]} VHDL PATH ../rtl/{f[0]}', "
                                f"got {' '.join(f)}")
        tops = [f[0] for f in vhdl if "TOP_LEVEL_FILE" in f[4:]]
        if tops != [f"{TOP_ENTITY}.vhd"]:
            problems.append(f"fileset {name}: TOP_LEVEL_FILE on {tops}, expected "
                            f"[{TOP_ENTITY}.vhd]")
    return problems


def avalon_problems(comp: Component, ports: list[Port]) -> list[str]:
    """The Avalon-MM slave: address width = avs_address_i, word addressing, fixed read latency
    2 (registered inputs, registered read data; no waitrequest and no variable latency), 32-bit
    data with 4 byte enables."""
    slaves = [n for n, (kind, d) in comp.interfaces.items() if kind == "avalon" and d == "end"]
    if len(slaves) != 1:
        return [f"expected exactly one Avalon-MM slave (avalon end), found {slaves}"]
    s = slaves[0]
    props = comp.iface_props[s]
    width = {p.name: p.width for p in ports}
    roles = {m.role: m for m in comp.ports if m.interface == s}
    problems = []
    addr = roles.get("address")
    if addr is None:
        problems.append(f"{s} has no address port")
    else:
        if addr.port != "avs_address_i":
            problems.append(f"{s}: address role on {addr.port}, expected avs_address_i")
        if addr.width != str(width.get("avs_address_i")):
            problems.append(f"{s}: address width {addr.width}, avs_address_i is "
                            f"{width.get('avs_address_i')} bits")
    expected_props = {"addressUnits": "WORDS", "readLatency": "2", "readWaitTime": "0",
                      "writeWaitTime": "0", "bitsPerSymbol": "8",
                      "associatedClock": "clock", "associatedReset": "reset"}
    problems += [f"{s}: {k} = {props.get(k)}, expected {v}" for k, v in expected_props.items()
                 if props.get(k) != v]
    problems += [f"{s}: role {r} present, but the core has no {r} (fixed latency, never stalls)"
                 for r in ("waitrequest", "readdatavalid", "burstcount") if r in roles]
    for r in ("read", "write", "writedata", "readdata", "byteenable"):
        if r not in roles:
            problems.append(f"{s} has no {r} port")
    if {"writedata", "readdata", "byteenable"} <= roles.keys():
        data_w = {roles["writedata"].width, roles["readdata"].width}
        if data_w != {str(8 * int(roles["byteenable"].width))}:
            problems.append(f"{s}: data widths {sorted(data_w)} do not match "
                            f"{roles['byteenable'].width} byte enables")
    return problems


def association_problems(comp: Component) -> list[str]:
    """associatedClock/Reset/AddressablePoint name interfaces of the right type."""
    kinds = {n: kind for n, (kind, _) in comp.interfaces.items()}
    want = {"associatedClock": "clock", "associatedReset": "reset",
            "associatedAddressablePoint": "avalon"}
    problems = []
    for iface, props in comp.iface_props.items():
        for prop, kind in want.items():
            target = props.get(prop)
            if target and kinds.get(target) != kind:
                problems.append(f"{iface}: {prop} {target} is not a {kind} interface")
    for n, kind in kinds.items():
        if kind in {"avalon", "interrupt", "reset"} and not comp.iface_props[n].get(
                "associatedClock"):
            problems.append(f"{n}: no associatedClock")
    irqs = [n for n, k in kinds.items() if k == "interrupt"]
    problems += [f"{n}: interrupt without associatedAddressablePoint" for n in irqs
                 if not comp.iface_props[n].get("associatedAddressablePoint")]
    return problems


def all_problems(tcl_text: str, vhdl_text: str, order: list[Path]) -> list[str]:
    comp = parse_component(tcl_text)
    generics, ports = entity_interface(vhdl_text)
    return (port_problems(comp, ports) + generic_problems(comp, generics)
            + fileset_problems(comp, order) + avalon_problems(comp, ports)
            + association_problems(comp))


# ------------------------------------------------------------------------------- the tests
@pytest.fixture(scope="module")
def comp() -> Component:
    return parse_component(HW_TCL.read_text())


@pytest.fixture(scope="module")
def entity() -> tuple[list[Generic], list[Port]]:
    return entity_interface(TOP_VHD.read_text())


def test_entity_parsed(entity):
    """The regexes read the whole entity (guards against a silently short list)."""
    generics, ports = entity
    assert len(generics) >= 15, [g.name for g in generics]
    assert len(ports) >= 21, [p.name for p in ports]
    assert {"CLK_FREQ_HZ", "CFG_DEPTH"} <= {g.name for g in generics}
    assert {"clk_i", "avs_address_i", "mcp_txrts_n_o", "ctrl_state_o"} <= {p.name for p in ports}


def test_every_port_mapped_once(comp, entity):
    problems = port_problems(comp, entity[1])
    assert not problems, "ip/canopen_master_hw.tcl ports:\n" + "\n".join(problems)


def test_every_generic_is_a_parameter(comp, entity):
    problems = generic_problems(comp, entity[0])
    assert not problems, "ip/canopen_master_hw.tcl parameters:\n" + "\n".join(problems)


def test_clock_rate_from_system_info(comp):
    """CLK_FREQ_HZ follows the clock connected to the clock interface."""
    assert comp.params["CLK_FREQ_HZ"].get("SYSTEM_INFO", "").split() == ["CLOCK_RATE", "clock"]
    assert comp.interfaces.get("clock") == ("clock", "end")


def test_filesets_equal_files_f(comp):
    problems = fileset_problems(comp, rtl_sources(FILES_F))
    assert not problems, "ip/canopen_master_hw.tcl filesets:\n" + "\n".join(problems)


def test_avalon_slave_matches_entity(comp, entity):
    problems = avalon_problems(comp, entity[1])
    assert not problems, "ip/canopen_master_hw.tcl Avalon slave:\n" + "\n".join(problems)


def test_interface_associations(comp):
    problems = association_problems(comp)
    assert not problems, "ip/canopen_master_hw.tcl associations:\n" + "\n".join(problems)
    assert comp.iface_props["irq"]["associatedAddressablePoint"] == "s0"
    assert comp.interfaces["reset"] == ("reset", "end")
    assert {m.role for m in comp.ports if m.interface == "reset"} == {"reset_n"}


def test_module_properties(comp):
    assert comp.module["NAME"] == "canopen_master"
    assert comp.module["VERSION"] == "1.0"
    for key in ("DISPLAY_NAME", "GROUP", "AUTHOR", "DESCRIPTION"):
        assert comp.module.get(key), f"module property {key} missing"


def _drop_line(text: str, pattern: str) -> str:
    out, n = re.subn(rf"^{pattern}[^\n]*\n", "", text, flags=re.MULTILINE)
    assert n >= 1, f"no line matches {pattern!r}"
    return out


def _sub_once(text: str, pattern: str, repl: str) -> str:
    out, n = re.subn(pattern, repl, text, count=1, flags=re.MULTILINE)
    assert n == 1, f"no match for {pattern!r}"
    return out


def test_checks_can_fail():
    """Doctored copies of the component and of the entity: every kind of drift is reported."""
    tcl, vhdl, order = HW_TCL.read_text(), TOP_VHD.read_text(), rtl_sources(FILES_F)
    assert all_problems(tcl, vhdl, order) == []

    # a port removed, another one mapped twice, a wrong width, a port that does not exist
    bad = _drop_line(tcl, r"add_interface_port irq irq_o ")
    bad = bad + "add_interface_port debug spi_sck_o sck_copy Output 1\n"
    bad = _sub_once(bad, r"(add_interface_port s0 avs_writedata_i\s+writedata\s+Input\s+)32",
                    r"\g<1>16")
    bad = bad + "add_interface_port debug ghost_o ghost Output 1\n"
    problems = all_problems(bad, vhdl, order)
    assert "port irq_o is in 0 add_interface_port lines (expected exactly 1)" in problems
    assert "port spi_sck_o is in 2 add_interface_port lines (expected exactly 1)" in problems
    assert "port avs_writedata_i: width 16, entity says 32" in problems
    assert any(p.startswith("add_interface_port debug ghost_o: no such port") for p in problems)
    assert any("data widths" in p for p in problems), problems

    # the same drift seen from the VHDL side: a new port and a wider address
    vhdl2 = _sub_once(vhdl, r"(avs_address_i\s*:\s*in\s+std_logic_vector\()7", r"\g<1>8")
    vhdl2 = _sub_once(vhdl2, r"(irq_o\s*:\s*out\s+std_logic;)", r"\1 extra_i : in std_logic;")
    problems = all_problems(tcl, vhdl2, order)
    assert "s0: address width 8, avs_address_i is 9 bits" in problems, problems
    assert "port avs_address_i: width 8, entity says 9" in problems
    assert "port extra_i is in 0 add_interface_port lines (expected exactly 1)" in problems

    # generics: a changed default, a lost range, a parameter removed, an extra HDL parameter
    bad = _sub_once(tcl, r"^(add_parameter MAX_NODES INTEGER )8", r"\g<1>9")
    bad = _sub_once(bad, r"^(set_parameter_property MAX_NODES DEFAULT_VALUE\s+)8", r"\g<1>9")
    bad = _sub_once(bad, r"^(set_parameter_property N_TPDO ALLOWED_RANGES\s+)1:32", r"\g<1>1:64")
    bad = _drop_line(bad, r"(add_parameter|set_parameter_property) CFG_DEPTH ")
    bad += "add_parameter BOGUS INTEGER 1\nset_parameter_property BOGUS HDL_PARAMETER true\n"
    problems = all_problems(bad, vhdl, order)
    assert "parameter MAX_NODES: default 9, generic default 8" in problems, problems
    assert "parameter N_TPDO: ALLOWED_RANGES 1:64, generic range 1:32" in problems
    assert "generic CFG_DEPTH has no add_parameter CFG_DEPTH" in problems
    assert f"HDL parameter BOGUS is no generic of {TOP_ENTITY}" in problems

    # filesets: files.f gains a file the component does not list; two files swapped
    problems = all_problems(tcl, vhdl, [*order[:-1], RTL_DIR / "new_block.vhd", order[-1]])
    assert sum(p.startswith("fileset ") and "rtl/files.f has" in p for p in problems) == 2
    first, second = order[0].name, order[1].name
    swapped = tcl.replace(f"add_fileset_file {first} ", "add_fileset_file @@ ")
    swapped = swapped.replace(f"add_fileset_file {second} ", f"add_fileset_file {first} ")
    swapped = swapped.replace("add_fileset_file @@ ", f"add_fileset_file {second} ")
    problems = all_problems(swapped, vhdl, order)
    assert any(p.startswith("fileset QUARTUS_SYNTH lists") for p in problems), problems
    problems = all_problems(_drop_line(tcl, r"add_fileset_file canopen_master\.sdc "), vhdl, order)
    assert any(p.startswith("fileset QUARTUS_SYNTH: non-VHDL files {}") for p in problems)

    # Avalon and associations: a waitrequest role, variable latency, a dangling association
    # (latency 1: the value before the Avalon inputs were registered)
    bad = _sub_once(tcl, r"^(set_interface_property s0 readLatency\s+)2", r"\g<1>1")
    bad = _sub_once(bad, r"^(set_interface_property irq associatedAddressablePoint )s0",
                    r"\1s1")
    bad += "add_interface_port s0 avs_readdatavalid_o readdatavalid Output 1\n"
    problems = all_problems(bad, vhdl, order)
    assert "s0: readLatency = 1, expected 2" in problems, problems
    assert any(p.startswith("s0: role readdatavalid present") for p in problems)
    assert "irq: associatedAddressablePoint s1 is not a avalon interface" in problems


def test_entity_parser_rejects_what_it_cannot_read():
    """A generic of a type the checker does not know stops the test instead of being skipped."""
    vhdl = _sub_once(TOP_VHD.read_text(), r"(CLK_FREQ_HZ\s*:)", r"USE_X : real := 1.0; \1")
    with pytest.raises(AssertionError, match="generic declaration this checker cannot read"):
        entity_interface(vhdl)


# ------------------------------------------------------------- the file as Tcl (optional)
TCL_HARNESS = r"""
package provide qsys 13.1
set ::calls {}
set ::params [dict create]
set ::msgs {}
proc _rec {args} { lappend ::calls $args }
foreach cmd {set_module_property add_fileset set_fileset_property add_fileset_file
             add_display_item set_parameter_property add_interface set_interface_property
             add_interface_port set_interface_assignment set_port_property
             set_module_assignment} {
    proc $cmd {args} "_rec $cmd {*}\$args"
}
proc add_parameter {name type {default ""} args} {
    _rec add_parameter $name $type $default {*}$args
    dict set ::params $name $default
}
proc get_parameter_value {name} { return [dict get $::params $name] }
proc send_message {level text} { lappend ::msgs [list $level $text] }
source [lindex $argv 0]
foreach {k v} [lrange $argv 1 end] { dict set ::params $k $v }
validate
elaborate
foreach c $::calls { puts "CALL\x1f[join $c \x1f]" }
foreach m $::msgs { puts "MSG\x1f[join $m \x1f]" }
"""


def _run_tcl(tmp_path: Path, **overrides: int) -> tuple[list[list[str]], list[list[str]]]:
    harness = tmp_path / "harness.tcl"
    harness.write_text(TCL_HARNESS)
    args = [str(x) for kv in overrides.items() for x in kv]
    out = subprocess.run([shutil.which("tclsh"), str(harness), str(HW_TCL), *args],
                         capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    rows = [line.split("\x1f") for line in out.stdout.splitlines()]
    return [r[1:] for r in rows if r[0] == "CALL"], [r[1:] for r in rows if r[0] == "MSG"]


@pytest.mark.skipif(shutil.which("tclsh") is None, reason="tclsh not installed")
def test_hw_tcl_runs_in_tclsh(tmp_path, comp):
    """Sourced with stub commands: valid Tcl, same commands as the regex parser, callbacks."""
    calls, msgs = _run_tcl(tmp_path)
    assert msgs == [], msgs
    executed = [PortMap(*c[1:6]) for c in calls if c[0] == "add_interface_port"]
    assert executed == comp.ports
    executed_params = {c[1]: c[3] for c in calls if c[0] == "add_parameter"}
    assert executed_params == {n: p.get("DEFAULT_VALUE") for n, p in comp.params.items()}
    macros = {c[1]: c[2] for c in calls if c[0] == "set_module_assignment"}
    assert macros["embeddedsw.CMacro.CLK_FREQ_HZ"] == "50000000"

    for overrides, expected in (
        ({"CLK_FREQ_HZ": 0}, "clock rate of the clock interface is unknown"),
        ({"CLK_FREQ_HZ": 50_500_000}, "whole number of MHz"),
        ({"CLK_FREQ_HZ": 12_000_000, "SPI_SCLK_HZ": 4_000_000}, "at least 4 x SPI_SCLK_HZ"),
        ({"SPI_SCLK_HZ": 6_000_000}, "maximum SCK of 5 MHz"),
        ({"OSC_FREQ_HZ": 30_000_000}, "maximum of 25 MHz"),
        ({"CAN_BITRATE_BPS": 5_000}, "10 kbit/s to 1 Mbit/s"),
    ):
        _, msgs = _run_tcl(tmp_path, **overrides)
        assert [m[0] for m in msgs] == ["error"] and expected in msgs[0][1], (overrides, msgs)
