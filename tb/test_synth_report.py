"""Checks of the figures ``make synth`` reports (``scripts/synth.py``), no simulation.

* ``logic_depth`` on a hand-made mapped netlist (Cyclone IV E cells written out in Verilog, read
  by yosys and exported with ``write_json``) whose longest register-to-register path is known:
  3 LUTs with an inverter between two of them; the registers cut the paths (a path through
  them would be longer and closes a loop).
* the whole flow (GHDL synthesis, ``synth_intel -family cycloneive``, netlist analysis) on a
  tiny entity with a 64-input XOR between registers, an inferred 256 x 16 RAM with registered
  read and a combinational port-to-port path: FF count, one M9K of 4096 bits, a depth no lower
  than the 3 levels that 64 inputs need through 4-input LUTs.
* the doctored cases fail: a combinational loop, a latch, an M9K count the log does not match.
"""

from __future__ import annotations

import copy
import importlib.util
import json
import os
import shutil
import subprocess

import pytest

from tb.tblib.runner import ROOT

_spec = importlib.util.spec_from_file_location("synth", ROOT / "scripts" / "synth.py")
synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(synth)

YOSYS = shutil.which("yosys")
pytestmark = pytest.mark.skipif(YOSYS is None, reason="yosys not installed (make setup)")

_FF = ("dffeas {name} (.d({d}), .clk(clk), .clrn(rst_n), .prn(1'b1), .ena({ena}), "
       ".asdata(1'b0), .aload(1'b0), .sclr(1'b0), .sload(1'b0), .q({q}));")
_LUT = ("cycloneive_lcell_comb #(.lut_mask(16'h{mask}), .sum_lutc_input(\"datac\")) {name} "
        "(.dataa({a}), .datab({b}), .datac({c}), .datad({d}), .combout({y}));")

# f1 -> u1 -> ~ -> u2 -> u3 -> f2 (3 LUT levels, the inverter adds none);
# f2 -> u4 -> f3.ena (1); f3 -> u3 (closes a loop through registers only); p -> u5 -> y (port to
# port, 1); a[3:1] -> u1 -> ... -> f2 (port to register, 3)
HAND_NETLIST = "\n".join([
    "module hand (input clk, input rst_n, input [3:0] a, input p, output y, output z);",
    "  wire q1, q2, q3, l1, n1, l2, l3, l4, l5;",
    "  " + _FF.format(name="f1", d="a[0]", ena="1'b1", q="q1"),
    "  " + _LUT.format(mask="6996", name="u1", a="q1", b="a[1]", c="a[2]", d="a[3]", y="l1"),
    "  assign n1 = ~l1;",
    "  " + _LUT.format(mask="8888", name="u2", a="n1", b="q1", c="1'b1", d="1'b1", y="l2"),
    "  " + _LUT.format(mask="8888", name="u3", a="l2", b="q3", c="1'b1", d="1'b1", y="l3"),
    "  " + _FF.format(name="f2", d="l3", ena="1'b1", q="q2"),
    "  " + _LUT.format(mask="8888", name="u4", a="q2", b="p", c="1'b1", d="1'b1", y="l4"),
    "  " + _FF.format(name="f3", d="a[1]", ena="l4", q="q3"),
    "  " + _LUT.format(mask="8888", name="u5", a="p", b="a[0]", c="1'b1", d="1'b1", y="l5"),
    "  assign y = l5;",
    "  assign z = q3;",
    "endmodule",
])

TINY_VHDL = """\
library ieee;
use ieee.std_logic_1164.all;
use ieee.numeric_std.all;

entity tiny_depth is
    port (
        clk_i   : in    std_logic;
        rst_n_i : in    std_logic;
        a_i     : in    std_logic_vector(63 downto 0);
        b_i     : in    std_logic_vector(15 downto 0);
        we_i    : in    std_logic;
        addr_i  : in    std_logic_vector(7 downto 0);
        q_o     : out   std_logic;
        r_o     : out   std_logic;
        c_o     : out   std_logic
    );
end entity tiny_depth;

architecture rtl of tiny_depth is
    type ram_t is array (0 to 255) of std_logic_vector(15 downto 0);
    signal ram : ram_t;
    signal a_r : std_logic_vector(63 downto 0);
    signal rd  : std_logic_vector(15 downto 0);
    signal q_r : std_logic;
    signal r_r : std_logic;
begin
    reg_proc : process (clk_i, rst_n_i)
        variable x : std_logic;
    begin
        if rst_n_i = '0' then
            a_r <= (others => '0');
            q_r <= '0';
            r_r <= '0';
        elsif rising_edge(clk_i) then
            a_r <= a_i;
            x := '0';
            for i in a_r'range loop
                x := x xor a_r(i);
            end loop;
            q_r <= x;
            x := '0';
            for i in rd'range loop
                x := x xor rd(i);
            end loop;
            r_r <= x;
        end if;
    end process reg_proc;

    ram_proc : process (clk_i)
    begin
        if rising_edge(clk_i) then
            if we_i = '1' then
                ram(to_integer(unsigned(addr_i))) <= b_i;
            end if;
            rd <= ram(to_integer(unsigned(addr_i)));
        end if;
    end process ram_proc;

    q_o <= q_r;
    r_o <= r_r;
    c_o <= b_i(0) xor b_i(1) xor b_i(2) xor b_i(3) xor b_i(4);
end architecture rtl;
"""


def _hand_module(tmp_path) -> dict:
    (tmp_path / "hand.v").write_text(HAND_NETLIST + "\n")
    res = subprocess.run(
        [YOSYS, "-q", "-p", "read_verilog -lib +/intel/cycloneive/cells_sim.v; "
         "read_verilog hand.v; hierarchy -top hand; proc; opt_clean; write_json hand.json"],
        cwd=tmp_path, capture_output=True, text=True, timeout=60, check=False)
    assert res.returncode == 0, res.stderr
    return json.loads((tmp_path / "hand.json").read_text())["modules"]["hand"]


def test_logic_depth_hand_netlist(tmp_path):
    """Known depths of the hand-made netlist: 3 levels register to register (f1 to f2), the
    inverter not counted, the path through the registers not taken; 3 port to register."""
    module = _hand_module(tmp_path)
    assert synth.cell_counts(module) == {"dffeas": 3, "cycloneive_lcell_comb": 5, "$not": 1}
    depth = synth.logic_depth(module)
    assert depth == {"levels": 3, "levels_io": 3, "path_from": "q1", "path_to": "l3"}


def test_logic_depth_can_fail(tmp_path):
    """A combinational loop is an error; without the register f2 the path runs on to f3's
    enable (5 levels)."""
    module = _hand_module(tmp_path)
    # a LUT in place of f2 (d -> q combinational): the u3 -> u4 -> f3 path gets 5 levels
    bypass = copy.deepcopy(module)
    name, f2 = next((k, c) for k, c in bypass["cells"].items()
                    if c["type"] == "dffeas" and c["connections"]["q"] == _net(module, "q2"))
    bypass["cells"][name] = {
        "type": "cycloneive_lcell_comb",
        "port_directions": {"dataa": "input", "combout": "output"},
        "connections": {"dataa": f2["connections"]["d"], "combout": f2["connections"]["q"]},
    }
    assert synth.logic_depth(bypass)["levels"] == 5
    # and u4 feeding u3 as well: a loop u3 -> f2 (now a LUT) -> u4 -> u3
    loop = copy.deepcopy(bypass)
    u3 = next(c for c in loop["cells"].values() if c["connections"].get("combout")
              == _net(module, "l3"))
    u3["connections"]["datab"] = _net(module, "l4")
    with pytest.raises(ValueError, match="combinational loop"):
        synth.logic_depth(loop)


def _net(module: dict, name: str) -> list:
    return module["netnames"][name]["bits"]


@pytest.fixture(scope="module")
def tiny_flow(tmp_path_factory):
    work = tmp_path_factory.mktemp("synth")
    (work / "tiny_depth.vhd").write_text(TINY_VHDL)
    env = dict(os.environ, GHDL_BACKEND=os.environ.get("GHDL_BACKEND", "llvm"))
    for cmd in (["ghdl", "-a", f"--std={synth.STD}", "tiny_depth.vhd"],
                ["ghdl", "--synth", f"--std={synth.STD}", "--out=verilog", "tiny_depth"]):
        res = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True,
                             timeout=120, check=False)
        assert res.returncode == 0, res.stderr
    vfile = work / "tiny_depth.v"
    vfile.write_text(synth.add_case_defaults(res.stdout))
    return work, synth.synth_one("tiny_depth", "tiny_depth", vfile, work)


def test_synth_flow_tiny_entity(tiny_flow):
    """FFs, M9K and depth of the tiny entity through the flow of ``make synth``."""
    work, r = tiny_flow
    # 64 + 2 registers; the RAM's read register is inside the M9K
    assert r["ffs"] == 66, r
    assert (r["m9k"], r["ram_bits"], r["memories_in_logic"]) == (1, 4096, []), r
    # 64 inputs need at least 3 levels of 4-input LUTs; the 16-input XOR behind the RAM 2
    assert 3 <= r["levels"] <= 6, r
    # the 5-input XOR from ports to a port: 2 levels
    assert r["levels_io"] == 2, r
    assert "altsyncram" in (work / "tiny_depth.stat").read_text()


def test_synth_flow_can_fail(tiny_flow):
    """A netlist with a latch, and an M9K count the yosys log does not confirm, are refused."""
    work, _ = tiny_flow
    log = (work / "tiny_depth.yosys.log").read_text()
    net = {"modules": {"t": {"ports": {}, "netnames": {}, "cells": {
        "l": {"type": "$_DLATCH_P_", "port_directions": {"E": "input", "D": "input",
                                                          "Q": "output"},
              "connections": {"E": [2], "D": [3], "Q": [4]}}}}}}
    with pytest.raises(ValueError, match="latch"):
        synth.analyse_netlist(net, "t", log)
    net["modules"]["t"]["cells"] = {
        "r": {"type": "altsyncram", "port_directions": {}, "connections": {}}}
    assert synth.analyse_netlist(net, "t", log)["m9k"] == 1  # the log holds one M9K
    net["modules"]["t"]["cells"]["r2"] = net["modules"]["t"]["cells"]["r"]
    with pytest.raises(ValueError, match="altsyncram cells"):
        synth.analyse_netlist(net, "t", log)


def test_bench_metrics_from_report():
    """The figures issue 14 asks for reach ``build/bench/results.json`` under their names, the
    slopes per extra channel computed from the two builds of ``synth.SLOPES``."""
    spec = importlib.util.spec_from_file_location("bench", ROOT / "scripts" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)

    def build(luts, ffs, levels):
        return {"luts": luts, "ffs": ffs, "m9k": 4, "levels": levels}

    builds = {"canopen_master_top": build(17000, 8000, 9),
              "canopen_master_top_canopen_only": build(12000, 6000, 7),
              "canopen_master_top_canopen_only_pdo12": build(12800, 6400, 8),
              "canopen_master_top_canopen_only_sdo4": build(14000, 6900, 11)}
    report = {"builds": builds, "slopes": synth.slopes(builds), "max_lut_levels": 11}
    m = bench.synth_metrics(report)
    assert m["synth_canopen_master_top_luts"] == 17000
    assert (m["synth_canopen_master_top_canopen_only_luts"],
            m["synth_canopen_master_top_canopen_only_ffs"]) == (12000, 6000)
    assert m["synth_luts_per_extra_pdo_channel"] == 800 / 8  # 8+8 -> 12+12: 8 channels
    assert m["synth_luts_per_extra_sdo_channel"] == 2000 / 2  # N_SDO 2 -> 4
    assert m["synth_ffs_per_extra_sdo_channel"] == 900 / 2
    assert m["synth_max_lut_levels"] == 11
    assert m["synth_canopen_master_top_canopen_only_sdo4_levels"] == 11
