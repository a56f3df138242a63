#!/usr/bin/env python3
"""Check the sensitivity lists of the combinational processes in ``rtl/files.f``.

VHDL-93 has no ``process (all)``: a combinational process names the signals it reads, and a
missing name silently changes simulation (the process does not wake up on that signal) while
synthesis ignores the list. For every process without ``rising_edge``/``falling_edge`` this
script collects the signals and input ports its text reads (identifiers declared as a signal or
an ``in``/``inout`` port of the file, not counting plain assignment targets) and compares them
with the list. ``process (all)`` is reported as an error too (not VHDL-93).

Usage: ``sensitivity.py`` checks and exits 1 on any difference (``make lint``);
``sensitivity.py --suggest`` prints the list each combinational process needs.
A heuristic text scan, not a VHDL parser: it assumes one entity per file, no signal names
shadowed by variables, and no combinational process that reads a signal only through a
function declared outside it (functions and procedures of the architecture take parameters).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from synth import sources  # rtl/files.f in compile order (scripts/ is on sys.path)

ROOT = Path(__file__).resolve().parents[1]

PROC_RE = re.compile(r"^\s*(\w+)\s*:\s*process\s*(?:\(([^)]*)\))?\s*(?:is)?\s*$", re.I | re.M)
END_RE = re.compile(r"^\s*end\s+process\b", re.I | re.M)
IDENT_RE = re.compile(r"[A-Za-z]\w*")


def strip(text: str) -> str:
    """Text without comments, string literals and character/bit literals (same length)."""
    text = re.sub(r"--[^\n]*", lambda m: " " * len(m.group(0)), text)
    text = re.sub(r'"[^"\n]*"', lambda m: " " * len(m.group(0)), text)
    return re.sub(r"'.'", "   ", text)


def readable(text: str) -> set[str]:
    """Names of the signals and the in/inout ports declared in the file."""
    names: set[str] = set()
    for m in re.finditer(r"\bsignal\s+([\w\s,]+?)\s*:", text, re.I):
        names.update(n.strip().lower() for n in m.group(1).split(","))
    port = re.search(r"\bport\s*\((.*?)\)\s*;\s*end\s+entity", text, re.I | re.S)
    if port:
        for m in re.finditer(r"([\w\s,]+?)\s*:\s*(in|inout|buffer)\b", port.group(1), re.I):
            names.update(n.strip().lower() for n in m.group(1).split(",") if n.strip())
    return names


def reads(body: str, names: set[str]) -> set[str]:
    """Signals the process text reads: every name occurrence except a plain target."""
    found: set[str] = set()
    for m in IDENT_RE.finditer(body):
        name = m.group(0).lower()
        if name not in names:
            continue
        before = body[:m.start()].rstrip()
        if before.endswith((".", "'")):
            continue
        after = body[m.end():]
        # a target: the name (optionally with a static-looking index) followed by <=
        tgt = re.match(r"\s*(\([^;]*?\))?\s*<=", after)
        if tgt and (before.endswith((";", "then", "else", "begin", "loop", "=>"))
                    or before == ""):
            index = tgt.group(1) or ""
            found.update(n.lower() for n in IDENT_RE.findall(index) if n.lower() in names)
            continue
        found.add(name)
    return found


def processes(path: Path):
    """(label, list or None for 'all', body, line) of every combinational process."""
    text = strip(path.read_text())
    names = readable(text)
    for m in PROC_RE.finditer(text):
        end = END_RE.search(text, m.end())
        body = text[m.end():end.start()]
        if re.search(r"\b(rising_edge|falling_edge)\b", body, re.I):
            continue
        lst = m.group(2)
        given = None if lst is None or lst.strip().lower() == "all" else {
            n.strip().lower() for n in lst.split(",") if n.strip()}
        line = text.count("\n", 0, m.start()) + 1
        yield m.group(1), given, reads(body, names), line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suggest", action="store_true", help="print the needed lists")
    args = ap.parse_args()
    bad = 0
    for path in sources():
        for label, given, need, line in processes(path):
            where = f"{path.relative_to(ROOT)}:{line}: {label}"
            if args.suggest:
                print(f"{where}: ({', '.join(sorted(need))})")
                continue
            if given is None:
                print(f"{where}: process (all) is VHDL-2008; list: {', '.join(sorted(need))}")
                bad += 1
                continue
            missing, extra = need - given, given - need
            if missing or extra:
                bad += 1
                print(f"{where}: missing {sorted(missing)} extra {sorted(extra)}")
    if not args.suggest:
        print(f"sensitivity: {f'{bad} process(es) wrong' if bad else 'all lists complete'}")
    sys.exit(1 if bad and not args.suggest else 0)


if __name__ == "__main__":
    main()
