"""Consistency checks between the VHDL sources and the Python models (no simulator).

* ``rtl/mcp2510_pkg.vhd`` and ``sim_models/mcp2510/regs.py`` are the two places where MCP2510
  opcodes, register addresses and bits are written down. Every ``constant MCP_<NAME>_C`` of the
  package must equal ``regs.<NAME>``, so the RTL and the model cannot drift apart (single
  source of truth by test). A VHDL constant without a counterpart in ``regs.py`` fails.
* The package must not define any MCP2515-only instruction (the MCP2510 does not have them).
* ``rtl/files.f`` (the compile order every flow reads) lists every ``rtl/*.vhd`` exactly once,
  packages come first, and a file that references ``work.<name>`` (a package or an
  entity) comes after the file declaring ``<name>``.

Each check is a function returning its findings; the ``*_can_fail`` tests feed it doctored
copies to prove it reports them.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pytest

from sim_models.mcp2510 import regs
from tb.tblib.runner import ROOT, RTL_DIR, rtl_sources

PKG = RTL_DIR / "mcp2510_pkg.vhd"
FILES_F = RTL_DIR / "files.f"

#: ``constant MCP_<NAME>_C : <type> := <value>;`` with a byte literal or an integer value
_CONST_RE = re.compile(
    r"^\s*constant\s+MCP_(?P<name>\w+?)_C\s*:\s*(?P<type>\w+)\s*:=\s*"
    r"(?:x\"(?P<hex>[0-9A-Fa-f]{2})\"|(?P<int>\d[\d_]*))\s*;",
    re.IGNORECASE,
)
#: any constant declaration of the MCP_..._C family, however its value is written
_ANY_CONST_RE = re.compile(r"^\s*constant\s+MCP_(\w+?)_C\b", re.IGNORECASE)

#: instruction bytes that exist on the MCP2515 only (READ RX BUFFER 0x90-0x96, LOAD TX BUFFER
#: 0x40-0x45, RX STATUS 0xB0)
MCP2515_ONLY_OPCODES = frozenset(range(0x90, 0x97)) | frozenset(range(0x40, 0x46)) | {0xB0}
MCP2515_ONLY_WORDS = ("READ_RX_BUFFER", "LOAD_TX_BUFFER", "RX_STATUS")
MCP2510_INSTRUCTIONS = {"INSTR_RESET", "INSTR_READ", "INSTR_WRITE", "INSTR_RTS",
                        "INSTR_READ_STATUS", "INSTR_BIT_MODIFY"}

_DECL_RE = re.compile(r"^\s*(package|entity)\s+(\w+)\s+is\b", re.IGNORECASE | re.MULTILINE)
#: a use of another unit of the library: ``use work.x_pkg.all`` or ``entity work.x``
_USE_RE = re.compile(r"\bwork\s*\.\s*(\w+)", re.IGNORECASE)


def _strip_comment(line: str) -> str:
    return line.split("--", 1)[0]


def _vhdl_text(path: Path) -> str:
    return "\n".join(_strip_comment(line) for line in path.read_text().splitlines())


# ------------------------------------------------------------------------------ the checks
def vhdl_constants(path: Path = PKG) -> dict[str, int]:
    """``{NAME: value}`` of every ``MCP_<NAME>_C`` constant with a literal value."""
    out: dict[str, int] = {}
    for line in _vhdl_text(path).splitlines():
        m = _CONST_RE.match(line)
        if m is None:
            continue
        name = m["name"].upper()
        if name in out:
            raise AssertionError(f"MCP_{name}_C declared twice in {path.name}")
        out[name] = int(m["hex"], 16) if m["hex"] else int(m["int"].replace("_", ""))
    return out


def declared_constant_names(path: Path = PKG) -> list[str]:
    """Names of every ``MCP_<NAME>_C`` constant, whatever its value is written as."""
    return [m[1].upper() for line in _vhdl_text(path).splitlines()
            if (m := _ANY_CONST_RE.match(line))]


def compare_with_regs(constants: dict[str, int], model=regs) -> list[str]:
    """Mismatches between VHDL constants and the model's ``regs`` module."""
    problems = []
    for name, value in sorted(constants.items()):
        expected = getattr(model, name, None)
        if not isinstance(expected, int):
            problems.append(f"MCP_{name}_C has no counterpart regs.{name} in "
                            "sim_models/mcp2510/regs.py")
        elif value != expected:
            problems.append(f"MCP_{name}_C = 0x{value:02X} but regs.{name} = 0x{expected:02X}")
    return problems


def mcp2515_only_instructions(path: Path = PKG) -> list[str]:
    """Instruction constants that are MCP2515-only (by value or by name)."""
    bad = [f"MCP_{n}_C = 0x{v:02X}" for n, v in vhdl_constants(path).items()
           if n.startswith("INSTR_") and v in MCP2515_ONLY_OPCODES]
    bad += [f"MCP_{n}_C" for n in declared_constant_names(path)
            if any(w in n for w in MCP2515_ONLY_WORDS)]
    return bad


def files_f_listing_problems(files_f: Path = FILES_F, rtl_dir: Path = RTL_DIR) -> list[str]:
    """Files listed twice, listed but missing, or present in ``rtl_dir`` but not listed."""
    listed = [p.resolve() for p in rtl_sources(files_f)]
    problems = [f"{p.name} listed {c} times" for p, c in Counter(listed).items() if c > 1]
    problems += [f"{p.name} listed but does not exist" for p in listed if not p.is_file()]
    problems += [f"{p.name} is not a .vhd file" for p in listed if p.suffix != ".vhd"]
    on_disk = {p.resolve() for p in rtl_dir.glob("*.vhd")}
    problems += [f"{p.name} not listed" for p in sorted(on_disk - set(listed))]
    return problems


def compile_order_problems(files_f: Path = FILES_F) -> list[str]:
    """Uses of ``work.<name>`` before the file declaring it; packages after a file
    that declares no package."""
    order = rtl_sources(files_f)
    declared_in: dict[str, int] = {}
    has_package: list[bool] = []
    for i, path in enumerate(order):
        decls = _DECL_RE.findall(_vhdl_text(path))
        has_package.append(any(kind.lower() == "package" for kind, _ in decls))
        for _, name in decls:
            declared_in.setdefault(name.lower(), i)
    problems = []
    for i, path in enumerate(order):
        for name in sorted({n.lower() for n in _USE_RE.findall(_vhdl_text(path))}):
            j = declared_in.get(name)
            if j is None:
                problems.append(f"{path.name} uses work.{name}, declared in no file")
            elif j > i:
                problems.append(f"{path.name} (entry {i + 1}) uses work.{name}, "
                                f"declared later in {order[j].name} (entry {j + 1})")
    first_other = next((i for i, pkg in enumerate(has_package) if not pkg), len(order))
    problems += [f"package file {order[i].name} after {order[first_other].name}"
                 for i in range(first_other, len(order)) if has_package[i]]
    return problems


CONSTANTS = vhdl_constants()


# -------------------------------------------------------------------- VHDL package = regs.py
def test_every_package_constant_is_parsed():
    """Every MCP_..._C constant has a literal value this test can compare (none is skipped)."""
    unparsed = [n for n in declared_constant_names() if n not in CONSTANTS]
    assert not unparsed, (
        f"constants in {PKG.name} without an x\"HH\" or integer literal value: "
        + ", ".join(f"MCP_{n}_C" for n in unparsed)
    )
    assert len(CONSTANTS) >= 40, f"only {len(CONSTANTS)} constants parsed from {PKG.name}"


def test_package_equals_regs():
    problems = compare_with_regs(CONSTANTS)
    assert not problems, f"{PKG.name} differs from regs.py:\n" + "\n".join(problems)


@pytest.mark.parametrize("name", sorted(CONSTANTS))
def test_package_constant_equals_regs(name):
    """One item per constant, so a report names the exact constant that drifted."""
    assert compare_with_regs({name: CONSTANTS[name]}) == []


def test_package_has_no_mcp2515_only_instruction():
    bad = mcp2515_only_instructions()
    assert not bad, f"MCP2515-only instructions in {PKG.name}: {', '.join(bad)}"
    instrs = {n for n in CONSTANTS if n.startswith("INSTR_")}
    assert instrs == MCP2510_INSTRUCTIONS, sorted(instrs)


def test_package_checks_can_fail(tmp_path):
    """A doctored copy of the package: wrong value, unknown name, MCP2515-only opcodes."""
    text, n = re.subn(r'(constant\s+MCP_CNF1_C\s*:\s*byte_t\s*:=\s*)x"2A"', r'\1x"2B"',
                      PKG.read_text(), flags=re.IGNORECASE)
    assert n == 1, "MCP_CNF1_C not found in the package"
    text = text.replace("end package mcp2510_pkg;",
                        'constant MCP_NO_SUCH_REG_C : byte_t := x"01";\n'
                        'constant MCP_INSTR_LOAD_TX_C : byte_t := x"40";\n'
                        'constant MCP_INSTR_RX_STATUS_C : byte_t := x"B0";\n'
                        "end package mcp2510_pkg;")
    bad_pkg = tmp_path / "mcp2510_pkg.vhd"
    bad_pkg.write_text(text)
    problems = compare_with_regs(vhdl_constants(bad_pkg))
    assert "MCP_CNF1_C = 0x2B but regs.CNF1 = 0x2A" in problems, problems
    assert any(p.startswith("MCP_NO_SUCH_REG_C has no counterpart") for p in problems)
    bad = mcp2515_only_instructions(bad_pkg)
    assert "MCP_INSTR_LOAD_TX_C = 0x40" in bad and "MCP_INSTR_RX_STATUS_C = 0xB0" in bad, bad
    # a model module lacking a name
    assert compare_with_regs({"CNF1": 0x2A}, SimpleNamespace()) != []


# ------------------------------------------------------------------------------- rtl/files.f
def test_files_f_lists_every_rtl_file_once():
    problems = files_f_listing_problems()
    assert not problems, "rtl/files.f:\n" + "\n".join(problems)


def test_files_f_declares_before_use():
    """A file using ``work.<name>`` (package or entity) comes after its declaration,
    and package files come first."""
    problems = compile_order_problems()
    assert not problems, "compile order in rtl/files.f:\n" + "\n".join(problems)


def test_files_f_checks_can_fail(tmp_path):
    """Reversed order, a duplicate, a missing and an unlisted file are all reported."""
    order = [p.resolve() for p in rtl_sources(FILES_F)]
    rev = tmp_path / "reversed.f"
    rev.write_text("\n".join(str(p) for p in reversed(order)) + "\n")
    problems = compile_order_problems(rev)
    assert any("uses work.mcp2510_pkg, declared later" in p for p in problems), problems
    assert any(p.startswith("package file mcp2510_pkg.vhd after") for p in problems), problems
    bad = tmp_path / "bad.f"
    bad.write_text("\n".join(str(p) for p in [order[0], order[0], *order[2:]])
                   + f"\n{tmp_path / 'ghost.vhd'}\n")
    problems = files_f_listing_problems(bad)
    assert f"{order[0].name} listed 2 times" in problems, problems
    assert "ghost.vhd listed but does not exist" in problems, problems
    assert f"{order[1].name} not listed" in problems, problems


# --------------------------------------------------------------------------- master FSM
FSM_PKG = ROOT / "rtl" / "canopen_master_pkg.vhd"
FSM_DOC = ROOT / "docs" / "fsm.md"


def vhdl_states(text: str) -> list[str]:
    body = re.search(r"type\s+state_t\s+is\s*\((.*?)\);", text, re.S | re.I)
    assert body, "state_t not found"
    names = re.sub(r"--[^\n]*", "", body.group(1))
    return [n.strip().upper() for n in names.split(",") if n.strip()]


def doc_tables(text: str) -> tuple[list[tuple[int, str]], list[tuple[str, str, str]]]:
    states = [(int(m.group(1)), m.group(2)) for m in
              re.finditer(r"^\| (\d+) \| `(S_\w+)` \|", text, re.M)]
    trans = [(m.group(1), m.group(2), m.group(3)) for m in
             re.finditer(r"^\| ([TG]\d+) \| ([^|]+?) \| (St\d+) \|", text, re.M)]
    return states, trans


def test_fsm_states_vhdl_equal_python_and_doc():
    from tb.tblib.fsm_states import State

    vhdl = vhdl_states(FSM_PKG.read_text())
    assert len(vhdl) == 14, vhdl
    assert vhdl == [s.name for s in State], "VHDL enum order differs from tb/tblib/fsm_states"
    states, _ = doc_tables(FSM_DOC.read_text())
    assert states == [(s.value, s.name) for s in State], "docs/fsm.md state table differs"


def test_fsm_transitions_doc_equal_python():
    from tb.tblib.fsm_states import THESIS_IDS, TRANSITIONS

    _, trans = doc_tables(FSM_DOC.read_text())
    expected = [(t.tid, "St2, St5–St12" if t.tid == "G4" else f"St{t.src.value}",
                 f"St{t.dst.value}") for t in TRANSITIONS]
    assert trans == expected, "docs/fsm.md transition table differs from tb/tblib/fsm_states"
    assert [t for t, _, _ in trans if t.startswith("T")] == list(THESIS_IDS)


def test_fsm_state_checker_can_fail():
    doctored = FSM_PKG.read_text().replace("S_PARSE,", "S_PARSE, S_EXTRA,")
    assert len(vhdl_states(doctored)) == 15


# --------------------------------------------------------------------------- Quartus project
def test_qsf_lists_rtl_files_in_compile_order():
    qsf = (ROOT / "constraints" / "ep3c80_reference.qsf").read_text()
    listed = re.findall(r"VHDL_FILE \.\./rtl/(\S+\.vhd) -library canopen_master", qsf)
    assert listed == [p.name for p in rtl_sources()], (
        "constraints/ep3c80_reference.qsf must list rtl/files.f in the same order")
