#!/usr/bin/env python3
"""FuseSoC generator ``canopen_master_netlist`` (``canopen_master.core``): GHDL synthesis of
``canopen_master_top`` to a Verilog netlist for the ``synth`` target's yosys run.

Edalize's yosys back end reads only Verilog, and Debian's yosys has no GHDL plugin, so the
VHDL goes through ``ghdl --synth --out=verilog`` first, with the same ``case``-default fix-up as
``make synth`` (``scripts/synth.py``). FuseSoC calls this script with the path of a YAML file
(``files_root``: the core's folder, ``vlnv``, ``parameters``: ``top`` and optional ``generics``,
a mapping of generic name to value) in the folder where the generated core must be written.
It writes ``<top>.v`` and ``<core name>.core`` (CAPI=2, one Verilog fileset) there.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml


def main(config_file: str) -> None:
    config = yaml.safe_load(Path(config_file).read_text())
    root = Path(config["files_root"])
    params = config.get("parameters") or {}
    top = params.get("top", "canopen_master_top")
    generics = [f"-g{k}={str(v).lower() if isinstance(v, bool) else v}"
                for k, v in (params.get("generics") or {}).items()]
    sys.path.insert(0, str(root / "scripts"))
    import synth  # the project's synthesis helpers: file list and the case fix-up

    env = dict(os.environ, GHDL_BACKEND=os.environ.get("GHDL_BACKEND", "llvm"))
    files = [str(p) for p in synth.sources()]
    work = Path.cwd()
    for cmd in (["ghdl", "-a", f"--std={synth.STD}", f"--work={synth.LIB}", *files],
                ["ghdl", "--synth", f"--std={synth.STD}", f"--work={synth.LIB}", *generics,
                 "--out=verilog", top]):
        res = subprocess.run(cmd, cwd=work, env=env, text=True, capture_output=True,
                             check=False)
        if res.returncode:
            sys.exit(f"{' '.join(cmd[:2])} failed:\n{res.stdout}{res.stderr}")
    netlist = work / f"{top}.v"
    netlist.write_text(synth.add_case_defaults(res.stdout))
    name = config["vlnv"]
    core = {"name": name,
            "filesets": {"netlist": {"files": [netlist.name], "file_type": "verilogSource"}},
            "targets": {"default": {"filesets": ["netlist"]}}}
    core_file = work / (name.split(":")[2] + ".core")
    core_file.write_text("CAPI=2:\n" + yaml.safe_dump(core, sort_keys=False))


if __name__ == "__main__":
    main(sys.argv[1])
